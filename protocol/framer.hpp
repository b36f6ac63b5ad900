// Incremental framing of a terminator-delimited byte stream (CR for ioport, LF for ID-2).
#pragma once

#include <cstddef>
#include <string>
#include <string_view>

namespace ioport {

struct Frame {
    std::string_view bytes;  // without the terminator; valid until the next feed()
    bool overflowed;         // the line ran past max_length: bytes holds only its start, never data
};

// Takes bytes as they arrive and yields complete frames. A line longer than max_length is cut
// to max_length and flagged, and the framer resynchronises on the next terminator, so noise can
// never grow the buffer or be mistaken for a frame.
class LineFramer {
  public:
    LineFramer(char terminator, std::size_t max_length)
        : terminator_(terminator), max_length_(max_length) {
        line_.reserve(max_length);
    }

    // Calls on_frame(Frame) for each frame completed by `bytes`, in order.
    template <class OnFrame>
    void feed(std::string_view bytes, OnFrame&& on_frame) {
        for (const char c : bytes) {
            if (c == terminator_) {
                on_frame(Frame{line_, overflowed_});
                line_.clear();
                overflowed_ = false;
            } else if (line_.size() < max_length_) {
                line_ += c;
            } else {
                overflowed_ = true;
            }
        }
    }

    // Bytes of an unfinished line are waiting.
    bool partial() const { return !line_.empty() || overflowed_; }
    void reset() {
        line_.clear();
        overflowed_ = false;
    }

  private:
    char terminator_;
    std::size_t max_length_;
    std::string line_;
    bool overflowed_ = false;
};

}  // namespace ioport
