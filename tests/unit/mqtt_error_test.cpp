#include "daemon/mqtt/mqtt_error.hpp"

#include <mosquitto.h>

#include <gtest/gtest.h>

namespace ioport::daemon {
namespace {

TEST(MosquittoError, EveryCodeOfTheLibraryHasWords) {
    // Debian 12's mosquitto_strerror() says "Unknown error." for MOSQ_ERR_KEEPALIVE and nine
    // more: an operator read "connection lost: Unknown error." when the broker stalled.
    for (int rc = MOSQ_ERR_AUTH_CONTINUE; rc <= MOSQ_ERR_ALREADY_EXISTS; ++rc) {
        if (rc == MOSQ_ERR_ERRNO) continue;
        const auto text = mosquitto_error(rc);
        EXPECT_EQ(text.find("nknown error."), std::string::npos) << rc << ": " << text;
        EXPECT_FALSE(text.empty()) << rc;
    }
}

TEST(MosquittoError, KeepaliveSaysTheBrokerStoppedAnswering) {
    EXPECT_EQ(mosquitto_error(MOSQ_ERR_KEEPALIVE),
              "no answer from the broker within the keepalive (the broker is stalled or the path "
              "to it drops packets)");
}

TEST(MosquittoError, ErrnoIsTheSystemsWords) {
    errno = ECONNREFUSED;
    EXPECT_EQ(mosquitto_error(MOSQ_ERR_ERRNO), "Connection refused");
}

TEST(MosquittoError, ACodeNobodyKnowsIsGivenByNumber) {
    EXPECT_EQ(mosquitto_error(1000), "libmosquitto error 1000");
    EXPECT_EQ(mosquitto_error(MOSQ_ERR_CONN_LOST), "The connection was lost.");
}

}  // namespace
}  // namespace ioport::daemon
