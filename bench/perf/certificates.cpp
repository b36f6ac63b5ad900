#include "bench/perf/certificates.hpp"

#include <filesystem>
#include <fstream>

#include <fmt/format.h>

namespace ioport::bench {

Certificates::Certificates(const Environment& env, const TempDir& dir) : env_(env), dir_(dir) {
    ok_ = key("ca") &&
          openssl({"req", "-x509", "-new", "-key", path("ca.key"), "-subj", "/CN=Bench Modbus CA",
                   "-days", "3650", "-out", path("ca.pem")}) &&
          signed_by_ca("server", "/CN=gateway1",
                       "subjectAltName=IP:127.0.0.1\nextendedKeyUsage=serverAuth\n") &&
          signed_by_ca(
              "operator", "/CN=hmi-1/O=Plant",
              fmt::format("extendedKeyUsage=clientAuth\n{}=ASN1:UTF8String:operator\n", role_oid));
    // ioportd refuses a key file that others may read.
    std::error_code ec;
    for (const auto* name : {"ca.key", "server.key", "operator.key"})
        std::filesystem::permissions(path(name), std::filesystem::perms(0640), ec);
}

std::string Certificates::yaml() const {
    return fmt::format(
        "  tls:\n    listen: \"127.0.0.1:0\"\n    certificate: {}\n    key: {}\n"
        "    client_ca: {}\n    roles:\n      operator: {{ units: all, access: read_write }}\n",
        path("server.pem"), path("server.key"), path("ca.pem"));
}

bool Certificates::openssl(std::vector<std::string> args) const {
    args.insert(args.begin(), env_.binaries.openssl);
    Process command(args, env_.placement.client_cpu, path("openssl.log"));
    return command.wait(30s) == 0;
}

bool Certificates::key(const std::string& name) const {
    return openssl({"genpkey", "-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256", "-out",
                    path(name + ".key")});
}

bool Certificates::signed_by_ca(const std::string& name, const std::string& subject,
                                const std::string& extensions) const {
    std::ofstream(path(name + ".ext")) << extensions;
    return key(name) &&
           openssl({"req", "-new", "-key", path(name + ".key"), "-subj", subject, "-out",
                    path(name + ".csr")}) &&
           openssl({"x509", "-req", "-in", path(name + ".csr"), "-CA", path("ca.pem"), "-CAkey",
                    path("ca.key"), "-CAcreateserial", "-days", "825", "-extfile",
                    path(name + ".ext"), "-out", path(name + ".pem")});
}

}  // namespace ioport::bench
