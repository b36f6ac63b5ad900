// ioportd logging to the systemd journal, received by the test itself: the daemon runs in a
// private mount namespace in which the test's datagram socket is /run/systemd/journal/socket,
// so the entries are read exactly as sd_journal_sendv() sent them (the native protocol).
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <array>
#include <cstring>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <regex>

#include <fmt/format.h>
#include <openssl/ssl.h>

#include "tests/support/beside_program.hpp"
#include "tests/support/datagram_socket.hpp"
#include "tests/support/gateway.hpp"
#include "tests/support/process.hpp"

namespace ioport::test {
namespace {

using Clock = std::chrono::steady_clock;
using Entry = std::map<std::string, std::string>;

// One datagram of the journal's native protocol: "KEY=value\n", or "KEY\n", a little-endian
// 64-bit length, the value and "\n" for values with newlines.
Entry parse_entry(std::string_view datagram) {
    Entry entry;
    while (!datagram.empty()) {
        const auto end = datagram.find('\n');
        if (end == std::string_view::npos) break;
        const auto line = datagram.substr(0, end);
        if (const auto equals = line.find('='); equals != std::string_view::npos) {
            entry[std::string(line.substr(0, equals))] = std::string(line.substr(equals + 1));
            datagram.remove_prefix(end + 1);
            continue;
        }
        std::uint64_t size = 0;
        if (datagram.size() < end + 1 + 8) break;
        std::memcpy(&size, datagram.data() + end + 1, 8);
        if (datagram.size() < end + 1 + 8 + size + 1) break;
        entry[std::string(line)] = std::string(datagram.substr(end + 1 + 8, size));
        datagram.remove_prefix(end + 1 + 8 + size + 1);
    }
    return entry;
}

// The journal's socket: the first entry whose MESSAGE contains `text`, or an empty one.
Entry wait_for_entry(DatagramSocket& journal, std::string_view text,
                     std::chrono::milliseconds within = 5s) {
    const auto deadline = Clock::now() + within;
    while (Clock::now() < deadline) {
        auto entry = parse_entry(journal.receive(deadline));
        if (entry["MESSAGE"].find(text) != std::string::npos) return entry;
    }
    return {};
}

bool can_make_mount_namespaces() {
    return run({"unshare", "--mount", "--propagation", "private", "true"}).exit_code == 0;
}

// ioportd in a mount namespace where `journal_dir` is /run/systemd/journal.
class JournaledGateway {
  public:
    JournaledGateway(const std::string& journal_dir, const std::string& yaml,
                     const std::vector<std::string>& extra,
                     const std::function<std::vector<std::string>(int log_fd)>& environment) {
        const auto config = dir_ / "ioportd.yaml";
        std::ofstream(config) << yaml;
        log_path_ = dir_ / "stderr.log";
        const int log_fd =
            ::open(log_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
        // In the new namespace: an empty /run, and the test's directory as its journal.
        const std::string script =
            "mount -t tmpfs tmpfs /run && mkdir -p /run/systemd/journal && "
            "mount --bind \"$0\" /run/systemd/journal && exec \"$@\"";
        std::vector<std::string> argv{"unshare",      "--mount",  "--propagation", "private",
                                      "/bin/sh",      "-c",       script,          journal_dir,
                                      IOPORTD_BINARY, "--config", config};
        argv.insert(argv.end(), extra.begin(), extra.end());
        pid_ = spawn(argv, log_fd, log_fd, environment(log_fd));
        ::close(log_fd);
    }
    ~JournaledGateway() {
        if (pid_ <= 0) return;
        ::kill(pid_, SIGTERM);
        if (wait_exit(pid_, Clock::now() + 5s) == -1) {
            ::kill(pid_, SIGKILL);
            wait_exit(pid_, Clock::now() + 5s);
        }
    }
    JournaledGateway(const JournaledGateway&) = delete;
    JournaledGateway& operator=(const JournaledGateway&) = delete;

    std::string stderr_text() const {
        std::ifstream in(log_path_);
        return {std::istreambuf_iterator<char>(in), {}};
    }

  private:
    TempDir dir_;
    std::string log_path_;
    pid_t pid_ = -1;
};

std::string hub_yaml(const std::string& device) {
    return fmt::format(R"(modbus: {{ listen: "127.0.0.1:0" }}
links:
  - {{ name: hub0, protocol: ioport, device: {}, unit_id: 7, timeout: 30ms,
      modules: [{{ type: dim16, number: 0 }}] }}
)",
                       device);
}

std::vector<std::string> no_environment(int /*log_fd*/) {
    return {};
}

// "device:inode" of a descriptor, as systemd writes JOURNAL_STREAM.
std::vector<std::string> journal_stream_of(int fd) {
    struct stat st {};
    ::fstat(fd, &st);
    return {fmt::format("JOURNAL_STREAM={}:{}", st.st_dev, st.st_ino)};
}

TEST(Journal, EntriesCarryPriorityAndTheLinkUnitAndModuleFields) {
    if (!can_make_mount_namespaces()) GTEST_SKIP() << "unshare --mount is not permitted here";
    SimProcess hub("--hub", "dim16:0", {"--no-line-timing"});
    TempDir journal;
    DatagramSocket socket(journal / "socket");
    JournaledGateway gateway(journal.path(), hub_yaml(hub.link()), {"--log", "journal"},
                             no_environment);

    auto online = wait_for_entry(socket, "dim16 0 online");
    ASSERT_FALSE(online.empty()) << "no journal entry; stderr:\n" << gateway.stderr_text();
    EXPECT_EQ(online["MESSAGE"], "link hub0: dim16 0 online");
    EXPECT_EQ(online["PRIORITY"], "6");
    EXPECT_EQ(online["SYSLOG_IDENTIFIER"], "ioportd");
    EXPECT_EQ(online["LINK"], "hub0");
    EXPECT_EQ(online["UNIT"], "7");
    EXPECT_EQ(online["MODULE"], "dim16 0");

    hub.ctl("unplug");
    auto down = wait_for_entry(socket, "port down");
    ASSERT_FALSE(down.empty());
    EXPECT_EQ(down["PRIORITY"], "4");
    EXPECT_EQ(down["LINK"], "hub0");
    EXPECT_EQ(down.count("MODULE"), 0U);
    EXPECT_EQ(gateway.stderr_text().find("online"), std::string::npos)
        << "journal lines went to stderr too";
}

// gateway.md §5.3: the communication-loss warning is one entry, with COMM_LOSS=1 to find it by.
TEST(Journal, CommunicationLossIsOneWarningWithTheCommLossField) {
    if (!can_make_mount_namespaces()) GTEST_SKIP() << "unshare --mount is not permitted here";
    SimProcess hub("--hub", "dom16:0", {"--no-line-timing"});
    TempDir journal;
    DatagramSocket socket(journal / "socket");
    JournaledGateway gateway(
        journal.path(),
        fmt::format(R"(modbus: {{ listen: "127.0.0.1:0", comm_loss_timeout: 300ms }}
links:
  - {{ name: hub0, protocol: ioport, device: {}, timeout: 30ms,
      modules: [{{ type: dom16, number: 0, initial: 0x00FF, safe: 0 }}] }}
)",
                    hub.link()),
        {"--log", "journal"}, no_environment);
    auto lost = wait_for_entry(socket, "no Modbus request from any client");
    ASSERT_FALSE(lost.empty()) << gateway.stderr_text();
    EXPECT_EQ(lost["PRIORITY"], "4");
    EXPECT_EQ(lost["COMM_LOSS"], "1");
    EXPECT_TRUE(wait_for_entry(socket, "no Modbus request from any client", 600ms).empty())
        << "logged more than once while nobody asked";
}

// gateway.md §5.4, issue 16: every client write that reaches a device is one notice with the
// audit fields, whatever its outcome.
TEST(Journal, EveryClientWriteIsOneNoticeWithTheAuditFields) {
    if (!can_make_mount_namespaces()) GTEST_SKIP() << "unshare --mount is not permitted here";
    SimProcess hub("--hub", "dom16:0", {"--no-line-timing"});
    TempDir journal;
    DatagramSocket socket(journal / "socket");
    JournaledGateway gateway(journal.path(),
                             fmt::format(R"(modbus: {{ listen: "127.0.0.1:0" }}
links:
  - {{ name: hub0, protocol: ioport, device: {}, unit_id: 7, timeout: 30ms,
      modules: [{{ type: dom16, number: 0, initial: 0 }}] }}
)",
                                         hub.link()),
                             {"--log", "journal"}, no_environment);
    // The port is in the journal, not on stderr.
    const auto listening = wait_for_entry(socket, "Modbus TCP on");
    std::smatch port;
    ASSERT_TRUE(std::regex_search(listening.at("MESSAGE"), port, std::regex(R"(:(\d+),)")))
        << gateway.stderr_text();
    ASSERT_FALSE(wait_for_entry(socket, "dom16 0 online").empty());
    ModbusClient client(static_cast<std::uint16_t>(std::stoi(port[1])), 7);
    ASSERT_TRUE(client.connected());
    sockaddr_in self{};
    socklen_t length = sizeof self;
    ::getsockname(modbus_get_socket(client.context()), reinterpret_cast<sockaddr*>(&self), &length);
    const auto me = fmt::format("127.0.0.1:{}", ntohs(self.sin_port));

    ASSERT_TRUE(client.write_register(0, 255));     // FC 06
    ASSERT_TRUE(client.write_coils(0, {1, 0, 1}));  // FC 15
    EXPECT_EQ(hub.ctl("get dom16:0"), "253\n");     // 0x00FF with output 1 off
    hub.ctl("fault dom16:0 silent");
    EXPECT_EQ(client.write_register(0, 0x0F0F).error(), 0x0B);  // no answer after the retries

    // Every entry that comes, until a while after the third audit entry: a duplicate would show.
    std::vector<Entry> audits;
    auto deadline = Clock::now() + 5s;
    while (Clock::now() < deadline) {
        const auto datagram = socket.receive(deadline);
        if (datagram.empty()) break;
        auto entry = parse_entry(datagram);
        if (entry.count("FUNCTION") == 0) continue;
        audits.push_back(std::move(entry));
        if (audits.size() == 3) deadline = std::min(deadline, Clock::now() + 500ms);
    }
    ASSERT_EQ(audits.size(), 3U);
    const std::vector<std::array<std::string, 4>> expected{{"6", "0", "255", "confirmed"},
                                                           {"15", "0", "1 0 1", "confirmed"},
                                                           {"6", "0", "3855", "no_answer"}};
    for (std::size_t i = 0; i < 3; ++i) {
        auto& entry = audits[i];
        SCOPED_TRACE(entry["MESSAGE"]);
        EXPECT_EQ(entry["PRIORITY"], "5");
        EXPECT_EQ(entry["CLIENT"], me);
        EXPECT_EQ(entry["UNIT"], "7");
        EXPECT_EQ(entry["LINK"], "hub0");
        EXPECT_EQ(entry["FUNCTION"], expected[i][0]);
        EXPECT_EQ(entry["ADDRESS"], expected[i][1]);
        EXPECT_EQ(entry["VALUE"], expected[i][2]);
        EXPECT_EQ(entry["RESULT"], expected[i][3]);
        EXPECT_TRUE(std::regex_match(entry["LATENCY_US"], std::regex("[0-9]+")))
            << entry["LATENCY_US"];
        EXPECT_TRUE(entry["MESSAGE"].starts_with(fmt::format(
            "write by {} to unit 7 (hub0): FC {:02} address {} values {}: {} in ", me,
            std::stoi(expected[i][0]), expected[i][1], expected[i][2], expected[i][3])));
    }
    // No answer comes after two tries of 30 ms each at least.
    EXPECT_GE(std::stoll(audits[2]["LATENCY_US"]), 60'000);
}

// A CA, the server's certificate and a client's with `role` (none when empty), made in `dir` with
// docs/tls.md's openssl commands.
void make_certificates(const TempDir& dir, const std::string& role) {
    const std::vector<std::string> ec{
        "openssl", "req",   "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256",
        "-noenc",  "-days", "30"};
    const auto req = [&](std::vector<std::string> rest) {
        auto argv = ec;
        argv.insert(argv.end(), rest.begin(), rest.end());
        ASSERT_EQ(run(argv).exit_code, 0) << fmt::format("{}", fmt::join(argv, " "));
    };
    req({"-keyout", dir / "ca.key", "-out", dir / "ca.pem", "-subj", "/CN=Journal CA"});
    req({"-keyout", dir / "server.key", "-out", dir / "server.pem", "-subj", "/CN=localhost", "-CA",
         dir / "ca.pem", "-CAkey", dir / "ca.key"});
    std::vector<std::string> client{"-keyout", dir / "client.key", "-out", dir / "client.pem",
                                    "-subj",   "/O=Plant/CN=hmi1", "-CA",  dir / "ca.pem",
                                    "-CAkey",  dir / "ca.key"};
    if (!role.empty()) {
        client.emplace_back("-addext");
        client.push_back("1.3.6.1.4.1.50316.802.1=ASN1:UTF8String:" + role);
    }
    req(client);
    ::chmod((dir / "server.key").c_str(), 0600);
}

// A TLS handshake with the client certificate of make_certificates(), then close: the server
// logs the client at connect. Returns the client's "127.0.0.1:port", or "" when it failed.
std::string tls_connect(const TempDir& dir, std::uint16_t port) {
    const std::unique_ptr<SSL_CTX, decltype(&SSL_CTX_free)> context(
        SSL_CTX_new(TLS_client_method()), SSL_CTX_free);
    if (SSL_CTX_use_certificate_file(context.get(), (dir / "client.pem").c_str(),
                                     SSL_FILETYPE_PEM) != 1 ||
        SSL_CTX_use_PrivateKey_file(context.get(), (dir / "client.key").c_str(),
                                    SSL_FILETYPE_PEM) != 1)
        return {};
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    const timeval deadline{5, 0};  // a server that never answers fails the test, not hangs it
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &deadline, sizeof deadline);
    sockaddr_in server{};
    server.sin_family = AF_INET;
    server.sin_port = htons(port);
    server.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    std::string me;
    if (::connect(fd, reinterpret_cast<const sockaddr*>(&server), sizeof server) == 0) {
        const std::unique_ptr<SSL, decltype(&SSL_free)> tls(SSL_new(context.get()), SSL_free);
        SSL_set_fd(tls.get(), fd);
        sockaddr_in self{};
        socklen_t length = sizeof self;
        ::getsockname(fd, reinterpret_cast<sockaddr*>(&self), &length);
        // The server logs the client once it has the client's Finished, which SSL_connect
        // sent before it returns.
        if (SSL_connect(tls.get()) == 1) me = fmt::format("127.0.0.1:{}", ntohs(self.sin_port));
        SSL_shutdown(tls.get());
    }
    ::close(fd);
    return me;
}

// Modbus/TCP Security (gateway.md §5.6): who connected, by certificate and role, in journal
// fields an operator can search for.
TEST(Journal, ATlsClientIsLoggedWithItsSubjectAndRole) {
    if (!can_make_mount_namespaces()) GTEST_SKIP() << "unshare --mount is not permitted here";
    SimProcess hub("--hub", "dim16:0", {"--no-line-timing"});
    TempDir certificates;
    make_certificates(certificates, "operator");
    TempDir journal;
    DatagramSocket socket(journal / "socket");
    JournaledGateway gateway(journal.path(),
                             fmt::format(R"(modbus:
  listen: ""
  tls:
    listen: "127.0.0.1:0"
    certificate: {0}
    key: {1}
    client_ca: {2}
    roles: {{ operator: {{ units: all, access: read_write }} }}
links:
  - {{ name: hub0, protocol: ioport, device: {3}, modules: [{{ type: dim16, number: 0 }}] }}
)",
                                         certificates / "server.pem", certificates / "server.key",
                                         certificates / "ca.pem", hub.link()),
                             {"--log", "journal"}, no_environment);
    const auto listening = wait_for_entry(socket, "Modbus/TCP Security (TLS) on");
    std::smatch port;
    ASSERT_TRUE(std::regex_search(listening.at("MESSAGE"), port, std::regex(R"(:(\d+),)")))
        << gateway.stderr_text();
    const auto me = tls_connect(certificates, static_cast<std::uint16_t>(std::stoi(port[1])));
    ASSERT_FALSE(me.empty());
    auto entry = wait_for_entry(socket, "Modbus/TCP Security client");
    SCOPED_TRACE(entry["MESSAGE"]);
    EXPECT_EQ(entry["PRIORITY"], "6");
    EXPECT_EQ(entry["CLIENT"], me);
    EXPECT_EQ(entry["TLS_SUBJECT"], "CN=hmi1,O=Plant");
    EXPECT_EQ(entry["ROLE"], "operator");
}

TEST(Journal, UnderSystemdStderrIsRecognisedAsTheJournalStream) {
    if (!can_make_mount_namespaces()) GTEST_SKIP() << "unshare --mount is not permitted here";
    SimProcess hub("--hub", "dim16:0", {"--no-line-timing"});
    TempDir journal;
    DatagramSocket socket(journal / "socket");
    JournaledGateway gateway(journal.path(), hub_yaml(hub.link()), {}, journal_stream_of);
    EXPECT_FALSE(wait_for_entry(socket, "dim16 0 online").empty()) << gateway.stderr_text();
}

TEST(Journal, AnotherStreamIsNotTheJournal) {
    if (!can_make_mount_namespaces()) GTEST_SKIP() << "unshare --mount is not permitted here";
    SimProcess hub("--hub", "dim16:0", {"--no-line-timing"});
    TempDir journal;
    DatagramSocket socket(journal / "socket");
    JournaledGateway gateway(journal.path(), hub_yaml(hub.link()), {},
                             [](int) { return std::vector<std::string>{"JOURNAL_STREAM=1:1"}; });
    // stderr with a timestamp and level: "2026-11-22 10:00:00.123 info link hub0: dim16 0 online"
    EXPECT_TRUE(eventually([&] {
        return gateway.stderr_text().find(" info link hub0: dim16 0 online") != std::string::npos;
    })) << gateway.stderr_text();
    EXPECT_TRUE(wait_for_entry(socket, "online", 200ms).empty());
}

}  // namespace
}  // namespace ioport::test
