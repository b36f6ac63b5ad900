#include "tests/support/process.hpp"
#include "tests/support/beside_program.hpp"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <array>
#include <cstdlib>
#include <cstring>
#include <iterator>

extern char** environ;

namespace ioport::test {
namespace {

using Clock = std::chrono::steady_clock;

int remaining_ms(Clock::time_point deadline) {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    return static_cast<int>(std::max<long long>(0, left.count()));
}

}  // namespace

pid_t spawn(const std::vector<std::string>& argv, int out_fd, int err_fd,
            const std::vector<std::string>& environment) {
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, out_fd, STDOUT_FILENO);
    if (err_fd >= 0) posix_spawn_file_actions_adddup2(&actions, err_fd, STDERR_FILENO);
    std::vector<char*> args;
    args.reserve(argv.size() + 1);
    for (const auto& arg : argv)
        args.push_back(const_cast<char*>(arg.c_str()));
    args.push_back(nullptr);
    std::vector<char*> env;
    for (char** entry = environ; *entry != nullptr; ++entry)
        env.push_back(*entry);
    for (const auto& entry : environment)
        env.push_back(const_cast<char*>(entry.c_str()));
    env.push_back(nullptr);
    pid_t pid = -1;
    const int rc = posix_spawnp(&pid, args[0], &actions, nullptr, args.data(), env.data());
    posix_spawn_file_actions_destroy(&actions);
    if (rc != 0) ADD_FAILURE() << "cannot start " << argv[0] << ": " << std::strerror(rc);
    return rc == 0 ? pid : -1;
}

int wait_exit(pid_t pid, std::chrono::steady_clock::time_point deadline) {
    // pidfd_open + poll: a bounded wait for a child without polling in a loop.
    const int pidfd = static_cast<int>(::syscall(SYS_pidfd_open, pid, 0));
    if (pidfd >= 0) {
        pollfd fd{pidfd, POLLIN, 0};
        ::poll(&fd, 1, remaining_ms(deadline));
        ::close(pidfd);
    }
    int status = 0;
    if (::waitpid(pid, &status, WNOHANG) != pid) return -1;
    if (WIFEXITED(status)) return WEXITSTATUS(status);
    return 128 + WTERMSIG(status);
}

Outcome run(const std::vector<std::string>& argv, std::chrono::milliseconds deadline_after) {
    std::array<int, 2> out{}, err{};
    if (::pipe2(out.data(), O_CLOEXEC) != 0 || ::pipe2(err.data(), O_CLOEXEC) != 0) return {};
    Outcome outcome;
    const pid_t pid = spawn(argv, out[1], err[1]);
    ::close(out[1]);
    ::close(err[1]);
    const auto deadline = Clock::now() + deadline_after;
    std::array<pollfd, 2> fds{pollfd{out[0], POLLIN, 0}, pollfd{err[0], POLLIN, 0}};
    int open_pipes = 2;
    while (pid > 0 && open_pipes > 0 && Clock::now() < deadline) {
        if (::poll(fds.data(), fds.size(), remaining_ms(deadline)) <= 0) break;
        for (std::size_t i = 0; i < fds.size(); ++i) {
            if (fds[i].fd < 0 || !(fds[i].revents & (POLLIN | POLLHUP))) continue;
            std::array<char, 4096> buffer{};
            const auto n = ::read(fds[i].fd, buffer.data(), buffer.size());
            if (n <= 0) {
                ::close(fds[i].fd);
                fds[i].fd = -1;
                --open_pipes;
            } else {
                (i == 0 ? outcome.out : outcome.err)
                    .append(buffer.data(), static_cast<std::size_t>(n));
            }
        }
    }
    for (const auto& fd : fds)
        if (fd.fd >= 0) ::close(fd.fd);
    if (pid > 0) {
        outcome.exit_code = wait_exit(pid, deadline);
        if (outcome.exit_code == -1) {
            ::kill(pid, SIGKILL);
            ::waitpid(pid, nullptr, 0);
            ADD_FAILURE() << argv[0] << " did not finish in time";
        }
    }
    return outcome;
}

Child::Child(const std::vector<std::string>& argv) {
    std::array<int, 2> out{};
    if (::pipe2(out.data(), O_CLOEXEC) != 0) return;
    pid_ = spawn(argv, out[1], -1);
    ::close(out[1]);
    out_fd_ = out[0];
}

Child::~Child() {
    if (pid_ > 0) stop(SIGTERM, 5s);
    if (out_fd_ >= 0) ::close(out_fd_);
}

std::string Child::read_line(std::chrono::milliseconds deadline_after) {
    const auto deadline = Clock::now() + deadline_after;
    for (;;) {
        if (const auto newline = buffered_.find('\n'); newline != std::string::npos) {
            std::string line = buffered_.substr(0, newline);
            buffered_.erase(0, newline + 1);
            return line;
        }
        pollfd fd{out_fd_, POLLIN, 0};
        if (out_fd_ < 0 || ::poll(&fd, 1, remaining_ms(deadline)) <= 0) return "";
        std::array<char, 1024> buffer{};
        const auto n = ::read(out_fd_, buffer.data(), buffer.size());
        if (n <= 0) return "";
        buffered_.append(buffer.data(), static_cast<std::size_t>(n));
    }
}

int Child::stop(int signal, std::chrono::milliseconds deadline) {
    if (pid_ <= 0) return -1;
    ::kill(pid_, signal);
    int code = wait_exit(pid_, Clock::now() + deadline);
    if (code == -1) {
        ::kill(pid_, SIGKILL);
        ::waitpid(pid_, nullptr, 0);
    }
    pid_ = -1;
    return code;
}

TempDir::TempDir() {
    std::string pattern = (std::filesystem::temp_directory_path() / "ioportd-test-XXXXXX").string();
    if (::mkdtemp(pattern.data()) == nullptr) ADD_FAILURE() << "mkdtemp: " << std::strerror(errno);
    path_ = pattern;
}

TempDir::~TempDir() {
    std::error_code ignored;
    std::filesystem::remove_all(path_, ignored);
}

SimProcess::SimProcess(const std::string& device_flag, const std::string& modules,
                       std::vector<std::string> extra)
    : link_(dir_ / "ttySIM"), control_(dir_ / "sim.ctl"), child_([&] {
          std::vector<std::string> argv{IOPORT_SIM_BINARY, "--link", link_,
                                        "--control",       control_, device_flag};
          if (!modules.empty()) argv.push_back(modules);
          argv.insert(argv.end(), extra.begin(), extra.end());
          return argv;
      }()) {
    // The simulator prints its banner once the link and the control socket exist.
    const auto banner = child_.read_line(10s);
    EXPECT_TRUE(banner.starts_with("ioport-sim: "))
        << "simulator did not start: '" << banner << "'";
    if (auto connected = client_.connect(control_); !connected)
        ADD_FAILURE() << connected.error().message;
}

Result<std::string> SimProcess::try_ctl(std::string_view command) {
    return client_.command(command);
}

std::string SimProcess::ctl(std::string_view command) {
    auto reply = client_.command(command);
    EXPECT_TRUE(reply) << command << ": " << reply.error().message;
    return reply.value_or("");
}

std::size_t open_descriptors(pid_t pid) {
    std::error_code ignored;
    const std::filesystem::directory_iterator fds("/proc/" + std::to_string(pid) + "/fd", ignored);
    return static_cast<std::size_t>(std::distance(begin(fds), end(fds)));
}

}  // namespace ioport::test
