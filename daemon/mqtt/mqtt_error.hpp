// libmosquitto's result codes (MOSQ_ERR_*) in words a person can act on.
#pragma once

#include <string>

namespace ioport::daemon {

// mosquitto_strerror() of Debian 12's libmosquitto (2.0.11) says "Unknown error." for ten codes
// it returns itself, MOSQ_ERR_KEEPALIVE among them (a broker that stopped answering PINGREQ):
// those get words here, and a code nobody knows gets its number.
std::string mosquitto_error(int rc);

}  // namespace ioport::daemon
