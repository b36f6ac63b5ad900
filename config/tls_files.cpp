#include "config/tls_files.hpp"

#include <sys/stat.h>

#include <array>
#include <cerrno>
#include <fstream>
#include <memory>
#include <system_error>

#include <fmt/format.h>
#include <openssl/bio.h>
#include <openssl/err.h>
#include <openssl/evp.h>
#include <openssl/pem.h>
#include <openssl/x509.h>

#include "protocol/openssl.hpp"

namespace ioport::config {
namespace {

// OpenSSL's reason for the last failure, which it queued, and the queue emptied.
std::string openssl_reason() {
    const unsigned long code = ERR_peek_last_error();
    ERR_clear_error();
    const char* reason = code != 0 ? ERR_reason_error_string(code) : nullptr;
    return reason != nullptr ? reason : "no PEM data";
}

constexpr std::size_t max_file_size = std::size_t{1024} * 1024;

Expected<std::string, std::string> read_file(const std::string& path, bool secret) {
    struct stat status {};
    if (::stat(path.c_str(), &status) != 0)
        return Unexpected(fmt::format("{}: {}", path, std::generic_category().message(errno)));
    if (!S_ISREG(status.st_mode)) return Unexpected(fmt::format("{} is not a file", path));
    if (secret && (status.st_mode & S_IROTH) != 0)
        return Unexpected(fmt::format(
            "{} is readable by every user: chmod o-r {} (group-readable is fine)", path, path));
    std::ifstream file(path);
    if (!file) return Unexpected(fmt::format("{}: cannot be read by this user", path));
    // Certificate chains are kilobytes; a file far larger is not one (nor read whole). Read in
    // pieces: a buffer of the limit's size, even freed, would stay in the daemon's heap.
    std::string text;
    std::array<char, 16384> piece{};
    while (file.read(piece.data(), piece.size()) || file.gcount() > 0) {
        text.append(piece.data(), static_cast<std::size_t>(file.gcount()));
        if (text.size() > max_file_size)
            return Unexpected(
                fmt::format("{} is larger than {} KiB: not a PEM file of certificates or a key",
                            path, max_file_size / 1024));
    }
    return text;
}

}  // namespace

Expected<std::string, std::string> read_certificates(const std::string& path) {
    auto text = read_file(path, false);
    if (!text) return text;
    const auto bio = openssl::memory(*text);
    int count = 0;
    while (
        openssl::Certificate certificate{PEM_read_bio_X509(bio.get(), nullptr, nullptr, nullptr)})
        ++count;
    // The loop ends at the end of the text (PEM_R_NO_START_LINE) or at a certificate that does
    // not parse.
    const unsigned long last = ERR_peek_last_error();
    if (count > 0 && ERR_GET_REASON(last) == PEM_R_NO_START_LINE) {
        ERR_clear_error();
        return text;
    }
    if (count == 0 && ERR_GET_REASON(last) == PEM_R_NO_START_LINE) {
        ERR_clear_error();
        return Unexpected(fmt::format(
            "{} has no PEM certificate (-----BEGIN CERTIFICATE-----): convert a DER file with "
            "openssl x509 -inform der -in FILE -out {}",
            path, path));
    }
    return Unexpected(
        fmt::format("{}: certificate {} does not parse: {}", path, count + 1, openssl_reason()));
}

Expected<std::string, std::string> read_private_key(const std::string& path) {
    auto text = read_file(path, true);
    if (!text) return text;
    const auto bio = openssl::memory(*text);
    // An encrypted key would need its passphrase at every start: no callback, so it fails here.
    const openssl::Key key(PEM_read_bio_PrivateKey(bio.get(), nullptr, nullptr, nullptr));
    if (!key)
        return Unexpected(fmt::format(
            "{} is not an unencrypted PEM private key ({}): write one with openssl pkey -in "
            "{} -out NEW_FILE",
            path, openssl_reason(), path));
    return text;
}

Expected<void, std::string> check_key_pair(const std::string& certificate_pem,
                                           const std::string& key_pem,
                                           const std::string& key_path) {
    const auto certificate_bio = openssl::memory(certificate_pem);
    const auto key_bio = openssl::memory(key_pem);
    const openssl::Certificate certificate(
        PEM_read_bio_X509(certificate_bio.get(), nullptr, nullptr, nullptr));
    const openssl::Key key(PEM_read_bio_PrivateKey(key_bio.get(), nullptr, nullptr, nullptr));
    if (!certificate || !key) {
        ERR_clear_error();
        return Unexpected(fmt::format("{} or its certificate does not parse", key_path));
    }
    if (X509_check_private_key(certificate.get(), key.get()) != 1) {
        ERR_clear_error();
        return Unexpected(fmt::format(
            "{} is not the key of the certificate (the first one in the certificate file): "
            "give the key the certificate was made for",
            key_path));
    }
    return {};
}

}  // namespace ioport::config
