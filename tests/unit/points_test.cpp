// The points of a module (protocol/points.hpp): the one list every output publishes, their
// values, what changed, and the one planner of a write. Moved here from the Sparkplug tests,
// whose metrics are these points under Sparkplug's names.
#include "protocol/points.hpp"

#include <gtest/gtest.h>

namespace ioport::gateway {
namespace {

using Values = std::vector<std::optional<PointValue>>;

Values values_of(std::optional<ModuleType> type, const ModuleReadings& now,
                 const ModuleTags& tags = no_tags) {
    Values values;
    point_values(type, now, tags, values);
    return values;
}

TEST(ModulePoints, EveryPointOfEveryModule) {
    const auto& dim = module_points(ModuleType::dim16);
    ASSERT_EQ(dim.size(), 17U);
    EXPECT_EQ(dim[0], (PointSpec{"in0", PointType::boolean, false}));
    EXPECT_EQ(dim[16], (PointSpec{"word", PointType::uint16, false}));
    EXPECT_EQ(module_points(ModuleType::dom16)[4], (PointSpec{"out4", PointType::boolean, true}));
    const auto& acm = module_points(ModuleType::acm3p);
    ASSERT_EQ(acm.size(), 6U);
    EXPECT_EQ(acm[2], (PointSpec{"raw2", PointType::uint16, false}));
    EXPECT_EQ(acm[3], (PointSpec{"value0", PointType::float32, false}));
    EXPECT_EQ(module_points(ModuleType::rgbdm),
              (std::vector<PointSpec>{{"colour", PointType::uint8, true}}));
    EXPECT_EQ(module_points(std::nullopt),
              (std::vector<PointSpec>{{"stop", PointType::boolean, false},
                                      {"count", PointType::uint16, false},
                                      {"reset", PointType::boolean, true, true}}));
    EXPECT_EQ(&module_points(ModuleType::dim16), &dim);  // made once
    EXPECT_EQ(find_point(ModuleType::mux8m, "neg")->index, 1U);
    EXPECT_FALSE(find_point(ModuleType::mux8m, "out0"));
}

TEST(ModulePoints, ValuesFollowThePoints) {
    const auto dim = values_of(ModuleType::dim16, {Reading{{0x8001, 0, 0}, 1}, {}, {}, {}});
    ASSERT_EQ(dim.size(), 17U);
    EXPECT_EQ(dim[0], PointValue(true));
    EXPECT_EQ(dim[1], PointValue(false));
    EXPECT_EQ(dim[15], PointValue(true));
    EXPECT_EQ(dim[16], PointValue(std::uint64_t{0x8001}));
    const auto acm = values_of(ModuleType::acm3p, {Reading{{0, 32768, 65535}, 3}, {}, {}, {}});
    ASSERT_EQ(acm.size(), 6U);
    EXPECT_EQ(acm[1], PointValue(std::uint64_t{32768}));
    EXPECT_EQ(acm[5], PointValue(100.0F));  // raw 65535 = full scale, 100 %
    EXPECT_EQ(values_of(ModuleType::mux8m, {{}, 0x0302, {}, {}}),
              (Values{PointValue(std::uint64_t{3}), PointValue(std::uint64_t{2})}));
    const auto never = values_of(ModuleType::dom16, {});
    ASSERT_EQ(never.size(), 17U);
    EXPECT_EQ(never[16], std::nullopt);
    EXPECT_EQ(values_of(std::nullopt, {{}, {}, true, 42}),
              (Values{PointValue(true), PointValue(std::uint64_t{42}), PointValue(false)}));
}

TEST(ModulePoints, ScaledChannelsHaveTheEngineeringValue) {
    auto tags = default_tags({ModuleType::acm3p, 0});
    tags.channels[0].scale = Scale{0, 100, -20, 150};
    const auto acm =
        values_of(ModuleType::acm3p, {Reading{{0, 32768, 65535}, 3}, {}, {}, {}}, tags);
    EXPECT_EQ(acm[3], PointValue(-20.0F));            // value0, scaled
    EXPECT_EQ(acm[0], PointValue(std::uint64_t{0}));  // raw0 as it was
    EXPECT_EQ(acm[5], PointValue(100.0F));            // value2, unscaled %
}

Values acm3p(std::uint16_t r0, std::uint16_t r1, std::uint16_t r2) {
    return values_of(ModuleType::acm3p, {Reading{{r0, r1, r2}, 3}, {}, {}, {}});
}

TEST(ModulePoints, AChannelsRawAndValueChangeTogetherOnlyBeyondTheDeadband) {
    // acm3p: raw0..2 are 0..2, value0..2 are 3..5; full scale 100 %, a raw step 0.0015 %
    const auto published = acm3p(1000, 2000, 100);
    // noise of a few raw steps on channel 1 within a deadband of 1 %: nothing
    for (const std::uint16_t noisy :
         {std::uint16_t{1995}, std::uint16_t{2003}, std::uint16_t{2400}})
        EXPECT_EQ(changed_points(ModuleType::acm3p, published, acm3p(1000, noisy, 100), 1.0),
                  std::vector<std::size_t>{})
            << noisy;
    // beyond it (+1.07 %): raw1 and value1, together
    EXPECT_EQ(changed_points(ModuleType::acm3p, published, acm3p(1000, 2700, 100), 1.0),
              (std::vector<std::size_t>{1, 4}));
    // compared with the last published value: a drift of small steps goes out once it adds up
    EXPECT_EQ(changed_points(ModuleType::acm3p, published, acm3p(1000, 1300, 100), 1.0),
              (std::vector<std::size_t>{1, 4}));
    // without a deadband, every change; two channels at once
    EXPECT_EQ(changed_points(ModuleType::acm3p, published, acm3p(1001, 2000, 101), 0.0),
              (std::vector<std::size_t>{0, 2, 3, 5}));
    // a channel read for the first time (was null) goes out whole
    const auto unread = values_of(ModuleType::acm3p, {});
    EXPECT_EQ(changed_points(ModuleType::acm3p, unread, published, 1.0),
              (std::vector<std::size_t>{0, 1, 2, 3, 4, 5}));
}

TEST(ModulePoints, OtherModulesChangeWithEveryValue) {
    EXPECT_EQ(changed_points(ModuleType::dom16, values_of(ModuleType::dom16, {{}, 0x0005, {}, {}}),
                             values_of(ModuleType::dom16, {{}, 0x0105, {}, {}}), 50.0),
              (std::vector<std::size_t>{8, 16}));  // out8 and word
    EXPECT_EQ(changed_points(std::nullopt, values_of(std::nullopt, {{}, {}, {}, 3}),
                             values_of(std::nullopt, {{}, {}, {}, 4}), 50.0),
              (std::vector<std::size_t>{1}));  // count
}

TEST(ModulePoints, OneWritePlanForEveryOutput) {
    const ModuleAddress dom{ModuleType::dom16, 1};
    EXPECT_EQ(plan_point_write(dom, "out3", 1)->changes,
              (std::vector<OutputChange>{{dom, 0x0008, 0x0008}}));
    EXPECT_EQ(plan_point_write(dom, "out15", 0)->changes,
              (std::vector<OutputChange>{{dom, 0x8000, 0x0000}}));
    EXPECT_EQ(plan_point_write(dom, "word", 0x1234)->changes,
              (std::vector<OutputChange>{{dom, 0xFFFF, 0x1234}}));
    const ModuleAddress mux{ModuleType::mux8m, 2};
    EXPECT_EQ(plan_point_write(mux, "pos", 3)->changes,
              (std::vector<OutputChange>{{mux, 0xFF00, 0x0300}}));
    EXPECT_EQ(plan_point_write(mux, "neg", 6)->changes,
              (std::vector<OutputChange>{{mux, 0x00FF, 0x0006}}));
    EXPECT_TRUE(plan_point_write(std::nullopt, "reset", 1)->reset_counter);
    EXPECT_FALSE(plan_point_write(std::nullopt, "reset", 0)->reset_counter);
    const auto why = [](std::optional<ModuleAddress> module, std::string_view id,
                        std::uint64_t value) {
        return plan_point_write(module, id, value).error().message;
    };
    EXPECT_EQ(why(dom, "out16", 1), "no such point");
    EXPECT_EQ(why(ModuleAddress{ModuleType::dim16, 0}, "in0", 1), "an input: it cannot be set");
    EXPECT_EQ(why(dom, "out0", 2), "2 is over 1");
    EXPECT_EQ(
        why(ModuleAddress{ModuleType::rgbdm, 0}, "colour", 8),
        "rgbdm colour 8 is out of range: use 0-7 (off red green blue cyan magenta yellow white)");
    EXPECT_EQ(why(mux, "pos", 8),
              "mux8m value 0x0800 is out of range: (pos << 8) | neg with pos and neg 0-7");
}

TEST(ModulePoints, TheWordsOfASet) {
    const auto& out0 = module_points(ModuleType::dom16)[0];
    EXPECT_EQ(*parse_point_text(out0, "ON"), 1U);
    EXPECT_EQ(*parse_point_text(out0, "false"), 0U);
    EXPECT_EQ(parse_point_text(out0, "yes").error().message,
              "'yes' is not allowed: send ON or OFF (or 1/0, true/false)");
    EXPECT_EQ(*parse_point_text(module_points(ModuleType::dom16)[16], "0x00F0"), 0xF0U);
    EXPECT_EQ(*parse_point_text(module_points(ModuleType::rgbdm)[0], "magenta"), 5U);
    EXPECT_FALSE(parse_point_text(module_points(ModuleType::mux8m)[0], "8"));
    EXPECT_FALSE(parse_point_text(module_points(ModuleType::acm3p)[3], "1"));  // a float
}

const ModuleAddress dim16{ModuleType::dim16, 0};
const ModuleAddress dom16{ModuleType::dom16, 1};
const ModuleAddress rgbdm{ModuleType::rgbdm, 2};
const ModuleAddress mux8m{ModuleType::mux8m, 0};

TEST(TextWrites, ModuleIds) {
    EXPECT_EQ(module_id(dim16), "dim16_0");
    EXPECT_EQ(module_id(std::nullopt), "id2");
}

TEST(TextWrites, WritesAsTheOneWritePathPlansThem) {
    const auto out3 = plan_text_write(dom16, "out3", "ON");
    ASSERT_TRUE(out3) << out3.error().message;
    EXPECT_EQ(out3->changes, (std::vector<OutputChange>{{dom16, 0x0008, 0x0008}}));
    EXPECT_EQ(plan_text_write(dom16, "out3", "0")->changes,
              (std::vector<OutputChange>{{dom16, 0x0008, 0x0000}}));
    EXPECT_EQ(plan_text_write(dom16, "word", "0x00F0")->changes,
              (std::vector<OutputChange>{{dom16, 0xFFFF, 0x00F0}}));
    EXPECT_EQ(plan_text_write(dom16, "word", "65535")->changes[0].value, 0xFFFF);
    EXPECT_EQ(plan_text_write(rgbdm, "colour", "magenta")->changes[0].value, 5);
    EXPECT_EQ(plan_text_write(rgbdm, "colour", "3")->changes[0].value, 3);
    EXPECT_EQ(plan_text_write(mux8m, "pos", "7")->changes,
              (std::vector<OutputChange>{{mux8m, 0xFF00, 0x0700}}));
    const auto reset = plan_text_write(std::nullopt, "reset", "ON");
    ASSERT_TRUE(reset) << reset.error().message;
    EXPECT_TRUE(reset->reset_counter);
}

TEST(TextWrites, AnythingElseIsRefusedSayingWhatIsAllowed) {
    const auto refused = [](std::optional<ModuleAddress> module, std::string_view point,
                            std::string_view payload, std::string_view why) {
        const auto plan = plan_text_write(module, point, payload);
        ASSERT_FALSE(plan) << point << " " << payload;
        EXPECT_EQ(plan.error().code, Errc::invalid_argument);
        EXPECT_NE(plan.error().message.find(why), std::string::npos) << plan.error().message;
    };
    refused(dom16, "out3", "yes", "'yes' is not allowed: send ON or OFF");
    refused(dom16, "out3", "ON ", "not allowed");
    refused(dom16, "out16", "ON", "no such point");
    refused(dom16, "out03", "ON", "no such point");
    refused(dom16, "word", "65536", "send a number 0-65535");
    refused(dom16, "word", "-1", "not allowed");
    refused(dom16, "word", "1.0", "not allowed");
    refused(dim16, "in3", "ON", "an input: it cannot be set");
    refused(dim16, "word", "1", "an input");
    refused(rgbdm, "colour", "pink", "send a colour: off, red");
    refused(rgbdm, "colour", "8", "send a colour");
    refused(mux8m, "neg", "8", "send a test point 0-7");
    refused(ModuleAddress{ModuleType::acm3p, 0}, "value0", "1", "an input");
    refused(std::nullopt, "count", "0", "an input");
    refused(dom16, "out3", std::string(33, '1'), "a value of 33 bytes: at most 32");
    refused(dom16, "out3\n", "ON", "no such point");
    refused(dom16, "out3", "\x1b[2J", "'\\x1B[2J' is not allowed");
}

}  // namespace
}  // namespace ioport::gateway
