#include "daemon/mqtt/mqtt_error.hpp"

#include <mosquitto.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <string_view>
#include <system_error>
#include <utility>

#include <fmt/format.h>

namespace ioport::daemon {
namespace {

constexpr std::array<std::pair<int, std::string_view>, 10> words_libmosquitto_lacks{{
    {MOSQ_ERR_UNKNOWN, "an unknown error inside libmosquitto"},
    {MOSQ_ERR_PLUGIN_DEFER, "deferred by a plugin"},
    {MOSQ_ERR_KEEPALIVE,
     "no answer from the broker within the keepalive (the broker is stalled or the path to it "
     "drops packets)"},
    {MOSQ_ERR_LOOKUP, "the broker's host name did not resolve"},
    {MOSQ_ERR_MALFORMED_PACKET, "a malformed packet from the broker"},
    {MOSQ_ERR_TIMEOUT, "timed out"},
    {MOSQ_ERR_RETAIN_NOT_SUPPORTED, "the broker does not take retained messages"},
    {MOSQ_ERR_TOPIC_ALIAS_INVALID, "an invalid topic alias"},
    {MOSQ_ERR_ADMINISTRATIVE_ACTION, "ended by the broker's administrator"},
    {MOSQ_ERR_ALREADY_EXISTS, "already exists"},
}};

}  // namespace

std::string mosquitto_error(int rc) {
    if (rc == MOSQ_ERR_ERRNO) return std::generic_category().message(errno);
    const auto* known =
        std::ranges::find(words_libmosquitto_lacks, rc, &std::pair<int, std::string_view>::first);
    if (known != words_libmosquitto_lacks.end()) return std::string(known->second);
    const std::string_view text = mosquitto_strerror(rc);
    if (text == "Unknown error.") return fmt::format("libmosquitto error {}", rc);
    return std::string(text);
}

}  // namespace ioport::daemon
