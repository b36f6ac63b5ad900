#include "daemon/core/model.hpp"

namespace ioport::daemon {

using gateway::ModuleStatus;

std::string_view status_text(ModuleStatus status) {
    switch (status) {
        case ModuleStatus::not_configured:
            return "not configured";
        case ModuleStatus::online:
            return "online";
        case ModuleStatus::no_answer:
            return "no answer";
        case ModuleStatus::bad_answer:
            return "bad answer";
        case ModuleStatus::not_polled:
            return "not polled yet";
    }
    return "unknown";
}

std::string_view to_string(WriteResult result) {
    switch (result) {
        case WriteResult::confirmed:
            return "confirmed";
        case WriteResult::error_ack:
            return "error_ack";
        case WriteResult::no_answer:
            return "no_answer";
        case WriteResult::link_down:
            return "link_down";
        case WriteResult::busy:
            return "busy";
        case WriteResult::dropped:
            return "dropped";
    }
    return "unknown";
}

}  // namespace ioport::daemon
