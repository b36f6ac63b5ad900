#include "config/loader.hpp"

namespace ioport::config::detail {
namespace {

constexpr std::array<std::string_view, 10> modbus_keys{
    "listen", "max_connections", "idle_timeout",      "allow", "read_only", "word_order",
    "stale",  "keepalive",       "comm_loss_timeout", "tls"};
constexpr std::array<std::pair<std::string_view, WordOrder>, 2> word_orders{
    {{"big", WordOrder::big}, {"little", WordOrder::little}}};
constexpr std::array<std::pair<std::string_view, Stale>, 2> stale_choices{
    {{"exception", Stale::exception}, {"hold", Stale::hold}}};

}  // namespace

void Loader::read_modbus(const Entry& entry, ModbusSettings& modbus) {
    if (entry.value.IsNull()) return;  // "modbus:" alone: every default
    const auto settings = mapping(entry, "modbus", modbus_keys, "{ listen: \"0.0.0.0:502\" }");
    if (!settings) return;
    const Fields& f = *settings;
    Endpoint listen{modbus.listen_host, modbus.listen_port};
    const Entry* off = f.find("listen");
    if (off != nullptr && off->value.IsScalar() && off->value.Scalar().empty()) {
        modbus.listen_host.clear();  // `listen: ""`: TLS only, or no Modbus at all
        modbus.listen_port = 0;
    } else if (read(f, "listen", "host:port, or \"\" for no plain Modbus TCP", listen,
                    [](const YAML::Node& value) { return parse_listen(value.Scalar()); })) {
        modbus.listen_host = listen.host;
        modbus.listen_port = listen.port;
    }
    read(f, "max_connections", "a number 1..65535", modbus.max_connections, integer(1, 65535));
    read(f, "idle_timeout", "a duration such as 5m, or 0 for never", modbus.idle_timeout,
         duration(microseconds{0}));
    read_allow(f, modbus.allow);
    read(f, "read_only", "true or false", modbus.read_only, boolean);
    read(f, "word_order", "big or little", modbus.word_order, choice<WordOrder>(word_orders));
    read(f, "stale", "exception or hold", modbus.stale, choice<Stale>(stale_choices));
    read(f, "keepalive", "a duration such as 60s, or 0 for off", modbus.keepalive,
         duration(microseconds{0}, 2h));
    read(f, "comm_loss_timeout", "a duration such as 10s, or 0 for off", modbus.comm_loss_timeout,
         duration(microseconds{0}, 24h));
    if (const Entry* tls = f.find("tls")) read_tls(*tls, modbus.tls);
    // Plain Modbus bypasses the roles: with TLS on, it runs only when asked for (gateway.md §5.6).
    modbus.listen_given = off != nullptr;
    if (modbus.tls && !modbus.listen_given) {
        modbus.listen_host.clear();
        modbus.listen_port = 0;
    }
}

}  // namespace ioport::config::detail
