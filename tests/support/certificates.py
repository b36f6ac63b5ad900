"""Certificates for the Modbus/TCP Security tests (gateway.md §5.6), made with the commands
docs/tls.md gives a person ("Making the certificates"): a CA, the gateway's certificate, clients
with a role in extension 1.3.6.1.4.1.50316.802.1. Keys are 0640, as ioportd refuses a key others
can read.

    certs = Certificates(directory)       # ca.pem/key, server.pem/key (CN gateway1)
    certs.client("operator", "operator")  # operator.pem/key
    ssl_context = certs.context("operator")
    certs.revoke("operator")               # openssl ca -revoke, in the CA's database
    certs.crl()                            # openssl ca -gencrl: crl.pem
"""

import os
import ssl
import subprocess

ROLE_OID = "1.3.6.1.4.1.50316.802.1"

# The least `openssl ca` needs to revoke certificates and issue CRLs: docs/tls.md's recipe.
CA_CONFIG = """[ca]
default_ca = plant
[plant]
database = index.txt
crlnumber = crlnumber
certificate = ca.pem
private_key = ca.key
default_md = sha256
"""


def openssl(*args, cwd):
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=30)


class Certificates:
    EC = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-noenc"]

    def __init__(self, directory):
        self.dir = directory
        self.ca("ca", "Plant Modbus CA")
        self.server("server", "gateway1")

    def path(self, name):
        return os.path.join(self.dir, name)

    def ca(self, name, cn):
        openssl("req", "-x509", *self.EC, "-keyout", f"{name}.key", "-out", f"{name}.pem",
                "-days", "3650", "-subj", f"/CN={cn}", cwd=self.dir)
        self._private(name)

    def signed(self, name, subject, extensions, ca="ca"):
        addext = [a for e in ["basicConstraints=critical,CA:FALSE", *extensions]
                  for a in ("-addext", e)]
        openssl("req", "-x509", *self.EC, "-keyout", f"{name}.key", "-out", f"{name}.pem",
                "-days", "825", "-subj", subject, "-CA", f"{ca}.pem", "-CAkey", f"{ca}.key",
                *addext, cwd=self.dir)
        self._private(name)

    def server(self, name, cn):
        self.signed(name, f"/CN={cn}", ["subjectAltName=DNS:localhost,IP:127.0.0.1",
                                        "extendedKeyUsage=serverAuth"])

    @staticmethod
    def role_extensions(role):
        return ["extendedKeyUsage=clientAuth"] + (
            [f"{ROLE_OID}=ASN1:UTF8String:{role}"] if role else [])

    def client(self, name, role, ca="ca"):
        """A client certificate with `role` (None: without the extension), subject
        CN=<name>-1, O=Plant."""
        self.signed(name, f"/CN={name}-1/O=Plant", self.role_extensions(role), ca)

    def expired(self, name, role):
        """`openssl req` refuses -days -1: an expired certificate is signed from a request by
        `openssl x509`."""
        openssl("req", "-new", *self.EC, "-keyout", f"{name}.key", "-out", f"{name}.csr",
                "-subj", f"/CN={name}-1/O=Plant", cwd=self.dir)
        with open(self.path(f"{name}.ext"), "w") as f:
            f.write("\n".join(self.role_extensions(role)) + "\n")
        openssl("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
                "-days", "-1", "-extfile", f"{name}.ext", "-out", f"{name}.pem", cwd=self.dir)
        self._private(name)

    def revoke(self, name):
        """Revokes name.pem in the CA's `openssl ca` database (made on first use)."""
        self._database()
        openssl("ca", "-config", "ca.cnf", "-batch", "-revoke", f"{name}.pem", cwd=self.dir)

    def crl(self, out="crl.pem", days=30):
        """The CA's CRL of the certificates revoked so far; its path."""
        self._database()
        openssl("ca", "-config", "ca.cnf", "-batch", "-gencrl", "-crldays", str(days),
                "-out", out, cwd=self.dir)
        return self.path(out)

    def _database(self):
        if os.path.exists(self.path("ca.cnf")):
            return
        with open(self.path("ca.cnf"), "w") as f:
            f.write(CA_CONFIG)
        open(self.path("index.txt"), "w").close()
        with open(self.path("crlnumber"), "w") as f:
            f.write("01\n")

    def context(self, client=None, **versions):
        """A client context that trusts the plant CA and shows `client`'s certificate."""
        context = ssl.create_default_context(cafile=self.path("ca.pem"))
        if client:
            context.load_cert_chain(self.path(f"{client}.pem"), self.path(f"{client}.key"))
        for attribute, version in versions.items():
            setattr(context, attribute, version)
        return context

    def _private(self, name):
        os.chmod(self.path(f"{name}.key"), 0o640)
