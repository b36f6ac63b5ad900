// The files of the TLS listener (gateway.md §5.6), read and checked with OpenSSL when the
// configuration is loaded, so that a wrong file is a configuration error naming it, not a
// listener that fails later. Messages name the file and say what to do.
#pragma once

#include <cstddef>
#include <string>

#include "protocol/expected.hpp"

namespace ioport::config {

// Whether others than the owner may read the file: a secret's may not be (the o+r bit).
enum class Secrecy { public_file, secret };

// The text of a file that grants rights (gateway.md §5.6: the configuration, the TLS files, an
// MQTT password file, the web configuration): a regular file owned by root or by the user this
// process runs as, that neither its group nor others may write, else whoever owns or can write it
// grants themselves a role. Checked with fstat on the opened descriptor, so that
// the file read is the file checked. At most `max_size` bytes.
Expected<std::string, std::string> read_protected_file(const std::string& path, Secrecy secrecy,
                                                       std::size_t max_size);

// PEM text with at least one certificate, each of which parses.
Expected<std::string, std::string> read_certificates(const std::string& path);
// A PEM private key, from a file that other users cannot read (the o+r bit).
Expected<std::string, std::string> read_private_key(const std::string& path);
// PEM CRLs (-----BEGIN X509 CRL-----) of the CAs in `client_ca_pem`: each one signed by one of
// them and not past its nextUpdate, and one for every CA there (a client of a CA without a CRL
// would fail its handshake with "unable to get certificate CRL").
Expected<std::string, std::string> read_crl(const std::string& path,
                                            const std::string& client_ca_pem,
                                            const std::string& client_ca_path);
// Whether the key is the one of the first certificate in `certificate_pem`.
Expected<void, std::string> check_key_pair(const std::string& certificate_pem,
                                           const std::string& key_pem, const std::string& key_path);

}  // namespace ioport::config
