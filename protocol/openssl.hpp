// OpenSSL's objects owned by std::unique_ptr, each freed by its own function: for the parts that
// read certificates and keys (protocol/modbus_security, config/tls_files, daemon/modbus_tls).
#pragma once

#include <memory>
#include <string_view>

#include <openssl/asn1.h>
#include <openssl/bio.h>
#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/x509.h>

namespace ioport::openssl {

template <auto Free>
struct Deleter {
    template <class T>
    void operator()(T* p) const {
        Free(p);
    }
};

using Bio = std::unique_ptr<BIO, Deleter<BIO_free>>;
using Certificate = std::unique_ptr<X509, Deleter<X509_free>>;
using Crl = std::unique_ptr<X509_CRL, Deleter<X509_CRL_free>>;
using Key = std::unique_ptr<EVP_PKEY, Deleter<EVP_PKEY_free>>;
using Object = std::unique_ptr<ASN1_OBJECT, Deleter<ASN1_OBJECT_free>>;
using String = std::unique_ptr<ASN1_STRING, Deleter<ASN1_STRING_free>>;

// OPENSSL_free is a macro: memory OpenSSL allocated for the caller.
struct BufferDeleter {
    void operator()(unsigned char* p) const { OPENSSL_free(p); }
};
using Buffer = std::unique_ptr<unsigned char, BufferDeleter>;

// A read-only BIO over `text`, which must outlive it.
inline Bio memory(std::string_view text) {
    return Bio(BIO_new_mem_buf(text.data(), static_cast<int>(text.size())));
}

}  // namespace ioport::openssl
