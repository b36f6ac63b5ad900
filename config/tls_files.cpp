#include "config/tls_files.hpp"

#include <fcntl.h>
#include <pwd.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <ctime>
#include <memory>
#include <optional>
#include <system_error>
#include <vector>

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

// Certificate chains, keys and a plant CA's CRL are kilobytes; a file far larger is none of them
// (nor read whole).
constexpr std::size_t max_pem_size = std::size_t{1024} * 1024;

std::string system_error(const std::string& path, int error) {
    return fmt::format("{}: {}", path, std::generic_category().message(error));
}

// "ioportd (uid 998)", or "uid 998" for a number without a name.
std::string user_text(uid_t uid) {
    passwd entry{};
    passwd* found = nullptr;
    std::array<char, 4096> buffer{};
    if (::getpwuid_r(uid, &entry, buffer.data(), buffer.size(), &found) == 0 && found != nullptr)
        return fmt::format("{} (uid {})", found->pw_name, uid);
    return fmt::format("uid {}", uid);
}

struct Descriptor {
    int fd = -1;
    ~Descriptor() {
        if (fd >= 0) ::close(fd);
    }
};

}  // namespace

Expected<std::string, std::string> read_protected_file(const std::string& path, Secrecy secrecy,
                                                       std::size_t max_size) {
    // O_NONBLOCK: a FIFO put in the file's place would block the open until a writer came.
    const Descriptor file{::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOCTTY | O_NONBLOCK)};
    if (file.fd < 0) {
        if (errno == EACCES)
            return Unexpected(fmt::format("{}: cannot be read by this user", path));
        return Unexpected(system_error(path, errno));
    }
    struct stat status {};
    if (::fstat(file.fd, &status) != 0) return Unexpected(system_error(path, errno));
    if (S_ISDIR(status.st_mode))
        return Unexpected(
            fmt::format("{} is not a file ({})", path, std::generic_category().message(EISDIR)));
    if (!S_ISREG(status.st_mode)) return Unexpected(fmt::format("{} is not a file", path));
    // As sshd does with its files: whoever owns a file can change its mode, and so its rights.
    if (status.st_uid != 0 && status.st_uid != ::geteuid())
        return Unexpected(fmt::format(
            "{} is owned by {}, neither root nor {}, the user ioportd runs as: its owner can "
            "change it and give themselves any right; chown root {}",
            path, user_text(status.st_uid), user_text(::geteuid()), path));
    const auto mode = status.st_mode & 07777;
    if ((status.st_mode & (S_IWGRP | S_IWOTH)) != 0)
        return Unexpected(fmt::format(
            "{} is writable by {} (mode {:04o}): whoever can write it can give themselves any "
            "right; chmod go-w {}",
            path, (status.st_mode & S_IWOTH) != 0 ? "every user" : "its group", mode, path));
    if (secrecy == Secrecy::secret && (status.st_mode & S_IROTH) != 0)
        return Unexpected(fmt::format(
            "{} is readable by every user: chmod o-r {} (group-readable is fine)", path, path));
    // Read in pieces: a buffer of the limit's size, even freed, would stay in the daemon's heap.
    std::string text;
    std::array<char, 16384> piece{};
    for (;;) {
        const auto n = ::read(file.fd, piece.data(), piece.size());
        if (n < 0 && errno == EINTR) continue;
        if (n < 0) return Unexpected(system_error(path, errno));
        if (n == 0) return text;
        text.append(piece.data(), static_cast<std::size_t>(n));
        if (text.size() > max_size)
            return Unexpected(fmt::format("{} is larger than {} KiB", path, max_size / 1024));
    }
}

namespace {

Expected<std::string, std::string> read_pem_file(const std::string& path, Secrecy secrecy,
                                                 std::string_view what) {
    auto text = read_protected_file(path, secrecy, max_pem_size);
    if (!text && text.error().find(" is larger than ") != std::string::npos)
        return Unexpected(fmt::format("{}: not {}", text.error(), what));
    return text;
}

}  // namespace

Expected<std::string, std::string> read_certificates(const std::string& path) {
    auto text = read_pem_file(path, Secrecy::public_file, "a PEM file of certificates");
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
    auto text = read_pem_file(path, Secrecy::secret, "a PEM private key");
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

namespace {

// "CN=Plant Modbus CA", for messages.
std::string name_text(const X509_NAME* name) {
    const openssl::Bio text(BIO_new(BIO_s_mem()));
    X509_NAME_print_ex(text.get(), name, 0, XN_FLAG_RFC2253);
    char* data = nullptr;
    const long length = BIO_get_mem_data(text.get(), &data);
    return data != nullptr && length > 0 ? std::string(data, static_cast<std::size_t>(length))
                                         : std::string("an empty name");
}

std::string time_text(const ASN1_TIME* time) {
    std::tm tm{};
    if (ASN1_TIME_to_tm(time, &tm) != 1) return "an unreadable time";
    return fmt::format("{:04}-{:02}-{:02} {:02}:{:02}:{:02} UTC", tm.tm_year + 1900, tm.tm_mon + 1,
                       tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec);
}

std::vector<openssl::Certificate> certificates_of(const std::string& pem) {
    std::vector<openssl::Certificate> certificates;
    const auto bio = openssl::memory(pem);
    while (
        openssl::Certificate certificate{PEM_read_bio_X509(bio.get(), nullptr, nullptr, nullptr)})
        certificates.push_back(std::move(certificate));
    ERR_clear_error();  // the end of the text
    return certificates;
}

// The CA of `cas` that signed `crl`, or nullopt.
std::optional<std::size_t> signer(X509_CRL* crl, const std::vector<openssl::Certificate>& cas) {
    for (std::size_t i = 0; i < cas.size(); ++i) {
        X509* ca = cas[i].get();
        if (X509_NAME_cmp(X509_get_subject_name(ca), X509_CRL_get_issuer(crl)) == 0 &&
            X509_CRL_verify(crl, X509_get0_pubkey(ca)) == 1)
            return i;
    }
    ERR_clear_error();
    return std::nullopt;
}

}  // namespace

Expected<std::string, std::string> read_crl(const std::string& path,
                                            const std::string& client_ca_pem,
                                            const std::string& client_ca_path) {
    auto text = read_pem_file(path, Secrecy::public_file, "a PEM CRL");
    if (!text) return text;
    const auto cas = certificates_of(client_ca_pem);
    std::vector<bool> covered(cas.size(), false);
    const auto bio = openssl::memory(*text);
    int count = 0;
    while (openssl::Crl crl{PEM_read_bio_X509_CRL(bio.get(), nullptr, nullptr, nullptr)}) {
        ++count;
        const auto issuer = name_text(X509_CRL_get_issuer(crl.get()));
        const auto ca = signer(crl.get(), cas);
        if (!ca)
            return Unexpected(fmt::format(
                "{}: CRL {} (issuer {}) is not signed by a CA of client_ca {}: make it with "
                "openssl ca -gencrl and the key of the CA that signs the clients' certificates",
                path, count, issuer, client_ca_path));
        const ASN1_TIME* next_update = X509_CRL_get0_nextUpdate(crl.get());
        if (next_update != nullptr && X509_cmp_current_time(next_update) < 0)
            return Unexpected(fmt::format(
                "{}: CRL {} (issuer {}) expired at {} (its nextUpdate), and with it every client "
                "would be refused: issue a new one with openssl ca -gencrl",
                path, count, issuer, time_text(next_update)));
        covered[*ca] = true;
    }
    const unsigned long last = ERR_peek_last_error();
    if (ERR_GET_REASON(last) != PEM_R_NO_START_LINE)
        return Unexpected(
            fmt::format("{}: CRL {} does not parse: {}", path, count + 1, openssl_reason()));
    ERR_clear_error();
    if (count == 0)
        return Unexpected(fmt::format(
            "{} has no PEM CRL (-----BEGIN X509 CRL-----): make one with openssl ca -gencrl -out "
            "{}, or convert a DER file with openssl crl -inform der -in FILE -out {}",
            path, path, path));
    for (std::size_t i = 0; i < cas.size(); ++i)
        if (!covered[i])
            return Unexpected(fmt::format(
                "{} has no CRL of {}, a CA in client_ca {}: with client_crl every CA there needs "
                "its CRL (openssl ca -gencrl), else all its clients are refused",
                path, name_text(X509_get_subject_name(cas[i].get())), client_ca_path));
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
