// A blocking client for one ioport hub, with the calls of the vendor's Windows library
// (ioportlib.dll / ioportnet.dll) under C++ names:
//
//   Open(port)            → open(device)           GetErr()           → last_error()
//   Close()               → close()                Update(name, n)    → update(module)
//   dim16Val(n, i)        → dim16(n, i)            lim16Val(n, i)     → lim16(n, i)
//   dom16Val(n, o, on)    → set_dom16(n, o, on)    rgbdmVal(n, c)     → set_rgbdm(n, colour)
//   acm3pVal(n, c)        → acm3p(n, c) percent    acm3cVal(n, c)     → acm3c(n, c) percent
//   dccimVal(n)           → dccim(n) amperes       dcvimVal(n)        → dcvim(n) volts
//   mux8mVal(n, p, m)     → set_mux8m(n, p, m)
//
// As in the vendor library, setters only stage a value; update() sends it. update() on an input
// module reads it; the getters return what the last update() read.
#pragma once

#include <array>
#include <chrono>
#include <optional>
#include <string>

#include "link/blocking_link.hpp"

namespace ioport {

struct HubOptions {
    int baud = 115200;
    std::chrono::microseconds timeout = 100ms;
    int retries = 0;
};

class Hub {
  public:
    Result<> open(const std::string& device, HubOptions options = {});
    void close();
    bool is_open() const { return link_ && link_->is_open(); }
    // Why the last failed call failed; empty if none has.
    const std::string& last_error() const { return last_error_; }

    // One transaction: reads an input module, or sends an output module its staged value.
    Result<> update(ModuleAddress module);
    Result<> update(std::string_view module_name, int number);

    Result<bool> dim16(int number, int input) const;
    Result<bool> lim16(int number, int input) const;
    Result<double> acm3p(int number, int channel) const;  // percent of range
    Result<double> acm3c(int number, int channel) const;  // percent of range
    Result<double> dccim(int number) const;               // amperes
    Result<double> dcvim(int number) const;               // volts
    // The last reading of an input module, raw.
    Result<Reading> reading(ModuleAddress module) const;

    Result<> set_dom16(int number, int output, bool on);
    Result<> set_dom16_word(int number, std::uint16_t word);
    Result<> set_rgbdm(int number, Colour colour);
    Result<> set_mux8m(int number, int pos, int neg);
    // The staged value of an output module (sent by the next update()).
    std::uint16_t staged(ModuleAddress module) const;

    // Round trip of the last successful update().
    std::chrono::microseconds last_round_trip() const {
        return link_ ? link_->last_round_trip() : std::chrono::microseconds{};
    }

  private:
    Result<ModuleAddress> address(ModuleType type, int number) const;
    Result<bool> input_bit(ModuleType type, int number, int input) const;
    Result<double> channel(ModuleType type, int number, int channel) const;
    template <class T>
    Result<T> record(Result<T> result) const;

    std::optional<BlockingLink> link_;
    std::array<std::optional<Reading>, slot_count> readings_{};
    std::array<std::uint16_t, slot_count> staged_{};
    mutable std::string last_error_;
};

}  // namespace ioport
