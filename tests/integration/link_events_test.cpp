// The core's one event bus and one write path (docs/design.md), against a hub the test scripts
// on a pty: every subscriber hears every event, typed and with what changed, and only until it
// lets go; a write is audited once, by the link, in its origin's words, whichever transport
// asked; the event log is a subscriber like any other.
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
        link =
            std::make_shared<LinkScheduler>(io.get_executor(), hub_link(device.path()), log, bus);
    }
    void TearDown() override { link->stop(); }

    asio::io_context io;
    PtyDevice device{io};
    Log log{Log::Target::standard_error, config::LogLevel::off};
    EventBus bus;
    std::uint16_t input = 0x0005;
    std::vector<std::uint16_t> written;
    std::shared_ptr<LinkScheduler> link;
};

// An event, as a subscriber can keep it after the call: its kind, the module's slot, the text.
struct Heard {
    std::size_t kind;  // the BusEvent alternative
    int slot = -1;
    std::string text{};
    std::optional<gateway::ModuleStatus> before{};
};
Heard heard(const BusEvent& event) {
    Heard h{.kind = event.index()};
    std::visit(
        [&](const auto& e) {
            using E = std::decay_t<decltype(e)>;
            if constexpr (std::is_same_v<E, ValuesChanged>) h.slot = e.module->slot;
            if constexpr (std::is_same_v<E, StatusChanged>) {
                h.slot = e.module->slot;
                h.text = e.text;
                h.before = e.before;
            }
            if constexpr (std::is_same_v<E, PortChanged> || std::is_same_v<E, WriteAudited>)
                h.text = e.text;
        },
        event);
    return h;
}
constexpr auto values_changed = BusEvent(std::in_place_type<ValuesChanged>).index();
constexpr auto status_changed = BusEvent(std::in_place_type<StatusChanged>).index();
constexpr auto port_changed = BusEvent(std::in_place_type<PortChanged>).index();
constexpr auto write_audited = BusEvent(std::in_place_type<WriteAudited>).index();

TEST_F(LinkEvents, EverySubscriberHearsEveryEventWithWhatChangedUntilItLetsGo) {
    std::vector<Heard> first;
    std::vector<Heard> second;
    auto first_subscription = bus.subscribe([&](const BusEvent& e) { first.push_back(heard(e)); });
    auto second_subscription =
        bus.subscribe([&](const BusEvent& e) { second.push_back(heard(e)); });
    link->start();
    const auto dim16_online = [](const std::vector<Heard>& seen) {
        return std::ranges::any_of(seen, [](const Heard& h) {
            return h.kind == status_changed && h.slot == 0 && !h.text.empty();
        });
    };
    ASSERT_TRUE(run_until(io, [&] { return dim16_online(first); }));
    EXPECT_EQ(first.front().kind, port_changed) << "the port opened first";
    EXPECT_TRUE(std::ranges::any_of(
        first, [](const Heard& h) { return h.kind == values_changed && h.slot == 0; }));
    const auto online = std::ranges::find_if(
        first, [](const Heard& h) { return h.kind == status_changed && h.slot == 0; });
    EXPECT_EQ(online->before, gateway::ModuleStatus::not_polled) << "the status it left";
    EXPECT_EQ(first.size(), second.size());
    // The model the event points at already holds the value, and its point values.
    ASSERT_NE(link->module_at(0), nullptr);
    ASSERT_TRUE(link->module_at(0)->reading);
    EXPECT_EQ(link->module_at(0)->reading->raw[0], 0x0005);
    EXPECT_EQ(link->module_at(0)->values[16], gateway::PointValue(std::uint64_t{0x0005}));
    EXPECT_EQ(link->module_at(0)->status(), gateway::ModuleStatus::online);

    second_subscription.reset();
    const auto heard_before = second.size();
    input = 0x0006;
    ASSERT_TRUE(run_until(io, [&] {
        return link->module_at(0)->reading && link->module_at(0)->reading->raw[0] == 0x0006;
    }));
    EXPECT_EQ(second.size(), heard_before) << "a subscriber that let go is not called";
    EXPECT_GT(first.size(), heard_before) << "the other one still is";
}

TEST_F(LinkEvents, TheEventLogIsASubscriberLikeAnyOther) {
    EventLog events;
    auto subscription = bus.subscribe([&](const BusEvent& e) { record(events, e); });
    link->start();
    ASSERT_TRUE(run_until(io, [&] { return link->modules_online() == 2; }));
    std::vector<EventKind> kinds;
    for (const auto& event : events.events())
        kinds.push_back(event.kind);
    EXPECT_EQ(kinds.front(), EventKind::port_up);
    EXPECT_EQ(std::ranges::count(kinds, EventKind::module_online), 2);
    EXPECT_EQ(events.events().back().link, "hub0");
    bus.publish(Note{.kind = EventKind::reload, .text = "configuration reloaded"});
    EXPECT_EQ(events.events().back().kind, EventKind::reload);
    EXPECT_EQ(events.events().back().text, "configuration reloaded");
}

TEST_F(LinkEvents, AWriteIsAuditedOnceByTheLinkInItsOriginsWords) {
    std::vector<std::string> audits;
    std::vector<std::size_t> kinds;
    auto subscription = bus.subscribe([&](const BusEvent& e) {
        kinds.push_back(e.index());
        if (const auto* audited = std::get_if<WriteAudited>(&e)) {
            EXPECT_EQ(audited->origin->client, "10.0.0.5:50123");
            EXPECT_EQ(audited->result, WriteResult::confirmed);
            audits.emplace_back(audited->text);
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
    const auto write_at = std::ranges::find(kinds, write_audited);
    EXPECT_NE(std::find(kinds.begin(), write_at, values_changed), write_at);
}

TEST_F(LinkEvents, TheSafeStateIsAuditedAsTheGatewaysOwnWrite) {
    std::vector<std::string> audits;
    auto subscription = bus.subscribe([&](const BusEvent& e) {
        if (const auto* audited = std::get_if<WriteAudited>(&e)) audits.emplace_back(audited->text);
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
