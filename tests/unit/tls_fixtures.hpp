// PEM fixtures for the unit tests of the TLS settings: a CA, a server certificate it signed,
// that certificate's key and another key. Made once with openssl (EC P-256, valid for 100
// years); they protect nothing.
#pragma once

namespace ioport::test::tls_fixtures {

inline constexpr const char* ca_pem = R"(-----BEGIN CERTIFICATE-----
MIIBlTCCATugAwIBAgIUaUXPpxBYsKrR1lkom7DhniYeMiEwCgYIKoZIzj0EAwIw
HzEdMBsGA1UEAwwUaW9wb3J0ZCB1bml0LXRlc3QgQ0EwIBcNMjYxMjAyMDcwNzUy
WhgPMjEyNjExMDgwNzA3NTJaMB8xHTAbBgNVBAMMFGlvcG9ydGQgdW5pdC10ZXN0
IENBMFkwEwYHKoZIzj0CAQYIKoZIzj0DAQcDQgAE3cwm+OkD6VFquQQvTG6T0AnC
WYwav9yhhqN1UbVBlwsKYC5UGxfzpDkLv+T9TgFLICSvGbmh66NzElGoSOknw6NT
MFEwHQYDVR0OBBYEFJtNL7ZRcHGaCv7uouH7R+glEbglMB8GA1UdIwQYMBaAFJtN
L7ZRcHGaCv7uouH7R+glEbglMA8GA1UdEwEB/wQFMAMBAf8wCgYIKoZIzj0EAwID
SAAwRQIgTIt/MDl/BhOAXBu5Z+GD/G3DpPBBRJ2tAr+1oTlPCnwCIQDseah0M5yr
zBQsvTCn6Aym/ha/qsJQoid+5okzPKD3hw==
-----END CERTIFICATE-----
)";

inline constexpr const char* server_pem = R"(-----BEGIN CERTIFICATE-----
MIIBNzCB3gIUPfCbz4+8a+g/Y5ST/EuTIwmnueEwCgYIKoZIzj0EAwIwHzEdMBsG
A1UEAwwUaW9wb3J0ZCB1bml0LXRlc3QgQ0EwIBcNMjYxMjAyMDcwNzUyWhgPMjEy
NjExMDgwNzA3NTJaMBwxGjAYBgNVBAMMEXVuaXQtdGVzdCBnYXRld2F5MFkwEwYH
KoZIzj0CAQYIKoZIzj0DAQcDQgAEIekeypOw0zhVDY6ku3k3XDwZWgRN3t4T9Su6
NWbX6lolavb99u8U32uXh772DJxKMFeNIfivJ3iWnATk7C357DAKBggqhkjOPQQD
AgNIADBFAiEA33YJC1898LuUpqdrRb1k/B/RC5ijN9XlcGLHL5WLA2ECIGDs6wNe
aAmM2OA3cSsRTqD1Qravid2CqOPnYknxSfPy
-----END CERTIFICATE-----
)";

inline constexpr const char* server_key = R"(-----BEGIN PRIVATE KEY-----
MIGHAgEAMBMGByqGSM49AgEGCCqGSM49AwEHBG0wawIBAQQgtwfjJnAyXN9Fy/IV
KED7iZxOvKsOvhITsEcQ6BXvYVyhRANCAAQh6R7Kk7DTOFUNjqS7eTdcPBlaBE3e
3hP1K7o1ZtfqWiVq9v327xTfa5eHvvYMnEowV40h+K8neJacBOTsLfns
-----END PRIVATE KEY-----
)";

inline constexpr const char* other_key = R"(-----BEGIN PRIVATE KEY-----
MIGHAgEAMBMGByqGSM49AgEGCCqGSM49AwEHBG0wawIBAQQgZuUC2ooq30FCHJLR
r5z0DNoaq0KdGCt8zoUm6WbPjf6hRANCAASmkJp2kVtX/XBE7dxh763tZtYv4Jbu
NVpQxtpg0zF+Qy7nR78xXP5p2IFuNM6y5wweDhhW/LMXocCEabOX+/Ur
-----END PRIVATE KEY-----
)";

}  // namespace ioport::test::tls_fixtures
