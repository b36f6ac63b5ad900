// What came back on the line while one request waited for its reply: the reply, or why it is
// not one. Pure: the link feeds it the bytes it read, in order.
//
// A reply names neither its module nor its request (protocol.md: an ioport read answers "400C"
// whoever asked, a command "1"), so an answer owed to an earlier request can only be told from
// the one in flight by what else is on the line. A device answers its requests in the order it
// read them and does not speak unasked; so when a device that buffered several requests (a
// stopped or starved device, one that answers later than the timeout) catches up, the first
// frame in the window is the oldest owed answer and the answer to the request in flight comes
// after it. One byte past the first frame therefore means the first frame may be stale: it is
// never the reply then (`State::extra`).
#pragma once

#include <cstddef>
#include <string>
#include <string_view>

#include "protocol/framer.hpp"

namespace ioport {

class ReplyWindow {
  public:
    enum class State {
        waiting,     // no complete frame yet
        complete,    // exactly one frame, and nothing after it so far
        overflowed,  // the first frame ran past the reply's length: malformed
        extra,       // bytes after the first frame: more than one answer, the first maybe stale
    };

    ReplyWindow(char terminator, std::size_t reply_length)
        : framer_(terminator, reply_length), terminator_(terminator) {}

    // Takes the next bytes read; the state after them. overflowed and extra are final.
    State feed(std::string_view bytes) {
        while (!bytes.empty()) {
            switch (state_) {
                case State::waiting: {
                    // Up to and including the first terminator: the candidate reply.
                    const auto end = bytes.find(terminator_);
                    const auto take = end == std::string_view::npos ? bytes.size() : end + 1;
                    framer_.feed(bytes.substr(0, take), [&](const Frame& frame) {
                        frame_.assign(frame.bytes);
                        state_ = frame.overflowed ? State::overflowed : State::complete;
                    });
                    bytes.remove_prefix(take);
                    break;
                }
                case State::complete:
                    state_ = State::extra;
                    extra_.assign(bytes.substr(0, 16));
                    return state_;
                case State::overflowed:
                case State::extra:
                    return state_;
            }
        }
        return state_;
    }

    State state() const { return state_; }
    // The first frame without its terminator (its start if it overflowed); empty while waiting.
    const std::string& frame() const { return frame_; }
    // The start of what came after the first frame (for a message), when extra.
    const std::string& extra() const { return extra_; }

  private:
    LineFramer framer_;
    char terminator_;
    State state_ = State::waiting;
    std::string frame_;
    std::string extra_;
};

}  // namespace ioport
