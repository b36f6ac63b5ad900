// The files of the TLS listener (gateway.md §5.6), read and checked with OpenSSL when the
// configuration is loaded, so that a wrong file is a configuration error naming it, not a
// listener that fails later. Messages name the file and say what to do.
#pragma once

#include <string>

#include "protocol/expected.hpp"

namespace ioport::config {

// PEM text with at least one certificate, each of which parses.
Expected<std::string, std::string> read_certificates(const std::string& path);
// A PEM private key, from a file that other users cannot read (the o+r bit).
Expected<std::string, std::string> read_private_key(const std::string& path);
// Whether the key is the one of the first certificate in `certificate_pem`.
Expected<void, std::string> check_key_pair(const std::string& certificate_pem,
                                           const std::string& key_pem, const std::string& key_path);

}  // namespace ioport::config
