// Ids that leave the box in MQTT and must stay unique after escaping: a client id made of the
// configuration's ids (gateway.md §5.5, §6.3). Pure.
#pragma once

#include <string>
#include <string_view>

namespace ioport {

// Letters and digits as they are, every other byte as '_' and two upper-case hex digits
// ("plant/line1" -> "plant_2Fline1", "plant_line1" -> "plant_5Fline1"): injective, so two
// different texts never give the same id, and never a '-', so ids joined by '-' stay apart.
std::string escaped_id(std::string_view text);

}  // namespace ioport
