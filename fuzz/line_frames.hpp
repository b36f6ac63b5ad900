// Serial replies as the link receives them: a byte stream read in chunks and framed by a
// LineFramer, as SerialLink::read_frame does with its 64-byte reads.
#pragma once

#include <algorithm>
#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

#include "fuzz/fuzz.hpp"
#include "protocol/framer.hpp"

namespace ioport::fuzz {

struct OwnedFrame {
    std::string bytes;
    bool overflowed = false;
    friend bool operator==(const OwnedFrame&, const OwnedFrame&) = default;
};

// The frames of `stream` fed to a LineFramer in reads of `chunk` bytes, checked against what the
// framer promises, worked out here the simple way: one frame per terminator, holding the first
// max_length bytes of its line, flagged when the line was longer; whatever the reads.
inline std::vector<OwnedFrame> line_frames(char terminator, std::size_t max_length,
                                           std::string_view stream, std::size_t chunk) {
    std::vector<OwnedFrame> expected;
    std::size_t line_start = 0;
    for (std::size_t end = stream.find(terminator); end != std::string_view::npos;
         end = stream.find(terminator, line_start)) {
        const auto line = stream.substr(line_start, end - line_start);
        expected.push_back({std::string(line.substr(0, max_length)), line.size() > max_length});
        line_start = end + 1;
    }
    const bool unfinished = line_start < stream.size();

    const auto framed = [&](std::size_t read_size) {
        LineFramer framer(terminator, max_length);
        std::vector<OwnedFrame> frames;
        for (std::size_t at = 0; at < stream.size(); at += read_size)
            framer.feed(stream.substr(at, read_size), [&](const Frame& frame) {
                frames.push_back({std::string(frame.bytes), frame.overflowed});
            });
        check(framer.partial() == unfinished, "partial() tells whether a line is unfinished");
        return frames;
    };
    check(framed(std::max<std::size_t>(chunk, 1)) == expected, "the frames of chunked reads");
    check(framed(std::max<std::size_t>(stream.size(), 1)) == expected, "the frames of one read");
    return expected;
}

}  // namespace ioport::fuzz
