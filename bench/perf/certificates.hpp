// The certificates of benchmarks 6d and 8, made with the openssl command as docs/tls.md tells an
// operator to (EC P-256): a CA, the server's certificate for 127.0.0.1, and an operator's client
// certificate with the role extension of gateway.md §5.6. tests/tls/modbus_tls_test.py makes its
// own the same way.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "bench/perf/harness.hpp"
#include "bench/perf/tls_client.hpp"

namespace ioport::bench {

// The role extension of gateway.md §5.6.
inline constexpr std::string_view role_oid = "1.3.6.1.4.1.50316.802.1";

class Certificates {
  public:
    // Made in `dir`, which must outlive this.
    Certificates(const Environment& env, const TempDir& dir);
    bool ok() const { return ok_; }
    std::string path(std::string_view name) const { return dir_ / name; }
    // What the openssl commands said.
    std::string log() const { return read_file(path("openssl.log")); }
    // A Modbus/TCP Security client: the CA, and the operator's certificate.
    TlsClientSettings client(int version = 0, bool no_tickets = false) const {
        return {path("ca.pem"), path("operator.pem"), path("operator.key"), version, no_tickets};
    }
    // The modbus.tls section.
    std::string yaml() const;

  private:
    bool openssl(std::vector<std::string> args) const;
    bool key(const std::string& name) const;
    bool signed_by_ca(const std::string& name, const std::string& subject,
                      const std::string& extensions) const;

    const Environment& env_;
    const TempDir& dir_;
    bool ok_ = false;
};

}  // namespace ioport::bench
