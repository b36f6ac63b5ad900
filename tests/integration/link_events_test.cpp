// The core's one event stream and one write path (docs/design.md), against a hub the test
// scripts on a pty: every subscriber hears every change, typed, and only until it lets go; a
// write is audited once, by the link, in its origin's words, whichever transport asked.
#include <gtest/gtest.h>

#include "daemon/core/link_scheduler.hpp"
#include "tests/support/pty_pair.hpp"

namespace ioport::daemon {
namespace {

using test::PtyDevice;
using test::run_until;

config::LinkConfig hub_link(const std::string& device) {
    config::LinkConfig link;
    link.name = "hub0";
    link.device = device;
    link.timeout = 200ms;
    link.modules = {config::ModuleConfig{.address = {ModuleType::dim16, 0}},
                    config::ModuleConfig{.address = {ModuleType::dom16, 0}}};
    return link;
}

// A hub whose dim16 0 reads `input` and whose dom16 0 acknowledges what it is sent.
class LinkEvents : public ::testing::Test {
  protected:
    void SetUp() override {
        device.serve([this](const std::string& frame) -> std::vector<test::Reply> {
            const auto request = parse_request(frame);
            if (!request) return {};
            if (is_output(request->module.type)) {
                written.push_back(request->output_value);
                return {{0ms, encode_ack(true)}};
            }
            return {{0ms, encode_reading(ModuleType::dim16, std::array{input})}};
        });
        link = std::make_shared<LinkScheduler>(io.get_executor(), hub_link(device.path()), log);
    }
    void TearDown() override { link->stop(); }

    asio::io_context io;
    PtyDevice device{io};
    Log log{Log::Target::standard_error, config::LogLevel::off};
    std::uint16_t input = 0x0005;
    std::vector<std::uint16_t> written;
    std::shared_ptr<LinkScheduler> link;
};

TEST_F(LinkEvents, EverySubscriberHearsEveryChangeTypedUntilItLetsGo) {
    std::vector<Change> first;
    std::vector<Change> second;
    auto first_subscription = link->subscribe([&](const Change& c) { first.push_back(c); });
    auto second_subscription = link->subscribe([&](const Change& c) { second.push_back(c); });
    link->start();
    const auto dim16_online = [](const std::vector<Change>& seen) {
        return std::ranges::any_of(seen, [](const Change& c) {
            return c.kind == Change::Kind::status && c.slot == 0 && c.event != nullptr;
        });
    };
    ASSERT_TRUE(run_until(io, [&] { return dim16_online(first); }));
    EXPECT_EQ(first.front().kind, Change::Kind::port) << "the port opened first";
    EXPECT_TRUE(std::ranges::any_of(
        first, [](const Change& c) { return c.kind == Change::Kind::values && c.slot == 0; }));
    EXPECT_EQ(first.size(), second.size());
    // The model the change points at already holds the value.
    ASSERT_NE(link->module_at(0), nullptr);
    ASSERT_TRUE(link->module_at(0)->reading);
    EXPECT_EQ(link->module_at(0)->reading->raw[0], 0x0005);
    EXPECT_EQ(link->module_at(0)->status(), gateway::ModuleStatus::online);

    second_subscription.reset();
    const auto heard = second.size();
    input = 0x0006;
    ASSERT_TRUE(run_until(io, [&] {
        return link->module_at(0)->reading && link->module_at(0)->reading->raw[0] == 0x0006;
    }));
    EXPECT_EQ(second.size(), heard) << "a subscriber that let go is not called";
    EXPECT_GT(first.size(), heard) << "the other one still is";
}

TEST_F(LinkEvents, AWriteIsAuditedOnceByTheLinkInItsOriginsWords) {
    std::vector<std::string> audits;
    std::vector<Change::Kind> kinds;
    auto subscription = link->subscribe([&](const Change& c) {
        kinds.push_back(c.kind);
        if (c.kind == Change::Kind::write) {
            ASSERT_NE(c.event, nullptr);
            EXPECT_EQ(c.event->kind, EventKind::write);
            EXPECT_EQ(c.event->client, "10.0.0.5:50123");
            audits.push_back(c.event->text);
        }
    });
    link->start();
    ASSERT_TRUE(run_until(io, [&] { return link->modules_online() == 2; }));
    gateway::WritePlan plan;
    plan.changes.push_back({ModuleAddress{ModuleType::dom16, 0}, 0xFFFF, 0x00A5});
    std::optional<WriteResult> result;
    // Named, not a braced temporary inside the co_await: g++ 12 freed such a temporary twice
    // here (a crash in free()). The daemon's callers hand over named origins too.
    WriteOrigin origin{.client = "10.0.0.5:50123",
                       .function = "6",
                       .address = "100",
                       .value = "165",
                       .request = "FC 06 address 100 values 165"};
    asio::co_spawn(
        io,
        [&]() -> asio::awaitable<void> { result = co_await link->write(plan, std::move(origin)); },
        asio::detached);
    ASSERT_TRUE(run_until(io, [&] { return result.has_value(); }));
    EXPECT_EQ(*result, WriteResult::confirmed);
    ASSERT_EQ(audits.size(), 1U);
    EXPECT_EQ(audits[0].rfind("write by 10.0.0.5:50123 to unit 1 (hub0): FC 06 address 100 "
                              "values 165: confirmed in ",
                              0),
              0U)
        << audits[0];
    EXPECT_EQ(std::ranges::count(written, std::uint16_t{0x00A5}), 1);
    EXPECT_EQ(link->module_at(slot({ModuleType::dom16, 0}))->output, 0x00A5);
    EXPECT_EQ(link->writes()[static_cast<std::size_t>(WriteResult::confirmed)], 1U);
    // The confirmed value came as a change of its own, before the audit.
    const auto write_at = std::ranges::find(kinds, Change::Kind::write);
    EXPECT_NE(std::find(kinds.begin(), write_at, Change::Kind::values), write_at);
}

TEST_F(LinkEvents, TheSafeStateIsAuditedAsTheGatewaysOwnWrite) {
    std::vector<std::string> audits;
    auto subscription = link->subscribe([&](const Change& c) {
        if (c.kind == Change::Kind::write) audits.push_back(c.event->text);
    });
    link->start();
    ASSERT_TRUE(run_until(io, [&] { return link->modules_online() == 2; }));
    link->enter_safe_state();
    ASSERT_TRUE(run_until(io, [&] { return !audits.empty(); }));
    EXPECT_EQ(audits[0].rfind("write by communication loss to unit 1 (hub0): safe value 0x0000 to "
                              "dom16 0: confirmed in ",
                              0),
              0U)
        << audits[0];
    EXPECT_EQ(link->writes()[static_cast<std::size_t>(WriteResult::confirmed)], 1U);
}

}  // namespace
}  // namespace ioport::daemon
