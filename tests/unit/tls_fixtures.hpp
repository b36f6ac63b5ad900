// PEM fixtures for the unit tests of the TLS settings: a CA, a server certificate it signed,
// that certificate's key and another key; CRLs of the CA (one revoking the server certificate, one
// past its nextUpdate) and one of an impostor CA with the same name but another key. Made once
// with openssl req and openssl ca -gencrl (EC P-256, valid for 100 years); they protect nothing.
#pragma once

namespace ioport::test::tls_fixtures {

inline constexpr const char* ca_pem = R"(-----BEGIN CERTIFICATE-----
MIIBlTCCATugAwIBAgIUU9Q4k94QOfqxQZiq1nDNPjW0DlkwCgYIKoZIzj0EAwIw
HzEdMBsGA1UEAwwUaW9wb3J0ZCB1bml0LXRlc3QgQ0EwIBcNMjYxMjAyMTY1MDAz
WhgPMjEyNjExMDgxNjUwMDNaMB8xHTAbBgNVBAMMFGlvcG9ydGQgdW5pdC10ZXN0
IENBMFkwEwYHKoZIzj0CAQYIKoZIzj0DAQcDQgAENOc5xE+4rEI/SzNRTFInR4Wa
A9Uu1JF5u1vju+NgzHmszg3/PrAivHKdIiBeO6iFQ5ZelcccKdisgDz9lma/x6NT
MFEwHQYDVR0OBBYEFA2HvoZiAxNa/sVvgJk3h4dy+XPbMB8GA1UdIwQYMBaAFA2H
voZiAxNa/sVvgJk3h4dy+XPbMA8GA1UdEwEB/wQFMAMBAf8wCgYIKoZIzj0EAwID
SAAwRQIgSgJS6zNR70NZfE3FkSzCUJt6Bd8bPsB2i50A4BWClXICIQDh/r8z3JT1
dlyUUbFPfQ1rJQ1AOy+q8xNy0DWn3bKYiQ==
-----END CERTIFICATE-----
)";

inline constexpr const char* server_pem = R"(-----BEGIN CERTIFICATE-----
MIIBkjCCATigAwIBAgIUOGE6AjVwWFgEAl+EirVhCUBr2t8wCgYIKoZIzj0EAwIw
HzEdMBsGA1UEAwwUaW9wb3J0ZCB1bml0LXRlc3QgQ0EwIBcNMjYxMjAyMTY1MDAz
WhgPMjEyNjExMDgxNjUwMDNaMBwxGjAYBgNVBAMMEXVuaXQtdGVzdCBnYXRld2F5
MFkwEwYHKoZIzj0CAQYIKoZIzj0DAQcDQgAEl2Q1KzLSLqz+vv3P/8xNxB6nRvB+
XtsbNEh1XDqlb7OVkQbZzVrB0hW7YtRP2aijtDobpLBZzkil19jndMH3kaNTMFEw
HQYDVR0OBBYEFBibzIhwf1eU5FTD/wEz1tNMhzZbMB8GA1UdIwQYMBaAFA2HvoZi
AxNa/sVvgJk3h4dy+XPbMA8GA1UdEwEB/wQFMAMBAf8wCgYIKoZIzj0EAwIDSAAw
RQIhAMuSPw+xLF/hyQcvL3IjLjX0Gl66Hzx74vnDvQxKn9pZAiAc0GT3GsTNlid+
Kq6MNrA9Di6z/ae0l4gevfoRdLdJAA==
-----END CERTIFICATE-----
)";

inline constexpr const char* server_key = R"(-----BEGIN PRIVATE KEY-----
MIGHAgEAMBMGByqGSM49AgEGCCqGSM49AwEHBG0wawIBAQQgpomlYmlwfiFLsPCn
OqNk2y4OQvJ2oNXJKCkCXJFjaGOhRANCAASXZDUrMtIurP6+/c//zE3EHqdG8H5e
2xs0SHVcOqVvs5WRBtnNWsHSFbti1E/ZqKO0OhuksFnOSKXX2Od0wfeR
-----END PRIVATE KEY-----
)";

inline constexpr const char* other_key = R"(-----BEGIN PRIVATE KEY-----
MIGHAgEAMBMGByqGSM49AgEGCCqGSM49AwEHBG0wawIBAQQgMO8FVJTg2K57lZk7
d/E+jDNLkZsonaAUFVxNfNWojDOhRANCAASKT2Y2Whbna4r81McKfg7TRRM68c5Z
payO4QfEFuS+6IohyncALZrL84vC2UQbkoknFa8Ao922U652K7RH90hO
-----END PRIVATE KEY-----
)";

inline constexpr const char* crl_pem = R"(-----BEGIN X509 CRL-----
MIHhMIGJAgEBMAoGCCqGSM49BAMCMB8xHTAbBgNVBAMMFGlvcG9ydGQgdW5pdC10
ZXN0IENBFw0yNjEyMDIwMDAwMDBaGA8yMTI2MTEwODAwMDAwMFowJzAlAhQ4YToC
NXBYWAQCX4SKtWEJQGva3xcNMjYxMjAyMTY1MDA0WqAOMAwwCgYDVR0UBAMCAQEw
CgYIKoZIzj0EAwIDRwAwRAIgZqeX8LueGBOype+1NiYTx1IPVTAs+8CYE392QuZo
QlUCIEpO53X9k2ARJ0cDyTmBljGxckcb8xNOpNvec/UxUNgH
-----END X509 CRL-----
)";

inline constexpr const char* expired_crl_pem = R"(-----BEGIN X509 CRL-----
MIHhMIGHAgEBMAoGCCqGSM49BAMCMB8xHTAbBgNVBAMMFGlvcG9ydGQgdW5pdC10
ZXN0IENBFw0yMDAxMDEwMDAwMDBaFw0yMDAyMDEwMDAwMDBaMCcwJQIUOGE6AjVw
WFgEAl+EirVhCUBr2t8XDTI2MTIwMjE2NTAwNFqgDjAMMAoGA1UdFAQDAgECMAoG
CCqGSM49BAMCA0kAMEYCIQCo8IDjZFcQoQ8pKzW+mNxBPW0j0ZQ+5xKgXAL6BCz9
bgIhAPXGnt2ToQnRLNG3+oxtAttdQd068LZqHY9F5LuFMKIr
-----END X509 CRL-----
)";

inline constexpr const char* impostor_crl_pem = R"(-----BEGIN X509 CRL-----
MIHhMIGJAgEBMAoGCCqGSM49BAMCMB8xHTAbBgNVBAMMFGlvcG9ydGQgdW5pdC10
ZXN0IENBFw0yNjEyMDIwMDAwMDBaGA8yMTI2MTEwODAwMDAwMFowJzAlAhQ4YToC
NXBYWAQCX4SKtWEJQGva3xcNMjYxMjAyMTY1MDA0WqAOMAwwCgYDVR0UBAMCAQMw
CgYIKoZIzj0EAwIDRwAwRAIgQqGowMFfdGnAiTrYfTBh21hfLM1HpuyMbIePEINN
UCkCIGZH10/92zkeEpCywvqOTsVX2hioYdiKweGrz3EBAuNq
-----END X509 CRL-----
)";

}  // namespace ioport::test::tls_fixtures
