// The tag model and the one value function of gateway.md §6.1.
#include "protocol/tags.hpp"

#include <bit>
#include <cstdint>

#include <gtest/gtest.h>

#include "protocol/gateway_map.hpp"

namespace ioport::gateway {
namespace {

constexpr ModuleType analog_types[] = {ModuleType::acm3p, ModuleType::acm3c, ModuleType::dccim,
                                       ModuleType::dcvim};

std::uint32_t bits(float value) {
    return std::bit_cast<std::uint32_t>(value);
}

TEST(ChannelValue, UnscaledIsTheVendorFloatBitForBit) {
    for (const auto type : analog_types)
        for (std::uint32_t raw = 0; raw <= 0xFFFF; ++raw) {
            const auto word = static_cast<std::uint16_t>(raw);
            ASSERT_EQ(bits(channel_value(type, word, std::nullopt)),
                      bits(engineering_float(type, word)))
                << name(type) << " raw " << raw;
        }
}

TEST(ChannelValue, ScaledIsTheDoubleFormulaRoundedOnce) {
    const Scale scale{0, 100, -20, 150};
    for (std::uint32_t raw = 0; raw <= 0xFFFF; raw += 7) {
        const auto word = static_cast<std::uint16_t>(raw);
        const double percent = word / 65535.0 * 100.0;
        const double expected = -20.0 + percent * 170.0 / 100.0;
        ASSERT_EQ(bits(channel_value(ModuleType::acm3p, word, scale)),
                  bits(static_cast<float>(expected)))
            << "raw " << raw;
    }
    // The ends land exactly on out_lo and out_hi.
    EXPECT_EQ(channel_value(ModuleType::acm3p, 0, scale), -20.0F);
    EXPECT_EQ(channel_value(ModuleType::acm3p, 65535, scale), 150.0F);
}

TEST(ChannelValue, IsNotClampedAndMayRunBackwards) {
    // 4–20 mA on 0–100 % is 20–100 %: a broken loop (0 %) reads below out_lo.
    EXPECT_EQ(channel_value(ModuleType::acm3c, 0, Scale{20, 100, 0, 10}), -2.5F);
    EXPECT_EQ(channel_value(ModuleType::acm3c, 65535, Scale{20, 100, 0, 10}), 10.0F);
    EXPECT_EQ(channel_value(ModuleType::dcvim, 0, Scale{0, 32, 100, 0}), 100.0F);
    EXPECT_EQ(channel_value(ModuleType::dcvim, 65535, Scale{0, 32, 100, 0}), 0.0F);
}

TEST(DefaultTags, NameTheModuleAndEachChannelInItsUnscaledUnit) {
    const auto acm3p = default_tags({ModuleType::acm3p, 2});
    EXPECT_EQ(acm3p.name, "acm3p 2");
    ASSERT_EQ(acm3p.channels.size(), 3U);
    EXPECT_EQ(acm3p.channels[0].unit, "%");
    EXPECT_EQ(acm3p.channels[2].range, (std::array<double, 2>{0, 100}));
    const auto dccim = default_tags({ModuleType::dccim, 0});
    ASSERT_EQ(dccim.channels.size(), 1U);
    EXPECT_EQ(dccim.channels[0].unit, "A");
    EXPECT_EQ(dccim.channels[0].range, (std::array<double, 2>{0, 6}));
    EXPECT_EQ(default_tags({ModuleType::dcvim, 0}).channels[0].unit, "V");
    EXPECT_TRUE(default_tags({ModuleType::dim16, 0}).channels.empty());
    EXPECT_TRUE(default_tags({ModuleType::rgbdm, 0}).channels.empty());
    EXPECT_EQ(default_range(ModuleType::acm3p, Scale{0, 100, 150, -20}),
              (std::array<double, 2>{-20, 150}));
}

TEST(TagText, NamesAndUnitsAreShortPrintableUtf8) {
    EXPECT_TRUE(check_tag_text("supply temperature", false));
    EXPECT_TRUE(check_tag_text("°C", false));
    EXPECT_TRUE(check_tag_text("m³/h", false));
    EXPECT_TRUE(check_tag_text("", true));
    EXPECT_TRUE(check_tag_text(std::string(64, 'x'), false));
    // 63 bytes and one two-byte character: 65 bytes.
    EXPECT_FALSE(check_tag_text(std::string(63, 'x') + "é", false));

    const auto refused = [](std::string_view text, std::string_view why) {
        const auto checked = check_tag_text(text, false);
        ASSERT_FALSE(checked) << text;
        EXPECT_NE(checked.error().message.find(why), std::string::npos) << checked.error().message;
    };
    refused("", "must not be empty");
    refused(std::string(65, 'x'), "is 65 bytes long");
    refused("door\topen", "control character at byte 4");
    refused("lamp\x7f", "control character at byte 4");
    refused("a\xc2\x85", "control character at byte 1");  // NEL, a C1 control
    refused("a\xff", "not valid UTF-8 at byte 1");
    refused("\xc3", "not valid UTF-8 at byte 0");          // cut short
    refused("\xed\xa0\x80", "not valid UTF-8 at byte 0");  // a surrogate
}

}  // namespace
}  // namespace ioport::gateway
