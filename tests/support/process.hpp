// Child processes for integration tests: the real binaries, with bounded waits only.
#pragma once

#include <sys/types.h>

#include <chrono>
#include <filesystem>
#include <string>
#include <vector>

#include "sim/control_client.hpp"
#include "tests/support/timing.hpp"

namespace ioport::test {

using namespace std::chrono_literals;

struct Outcome {
    int exit_code = -1;  // -1: killed at the deadline
    std::string out;
    std::string err;
};

// Starts argv[0] (searched in PATH unless it has a slash) with stdout (and stderr unless err_fd <
// 0) on the given descriptors and `environment` (NAME=VALUE) added to the test's own; -1 (and a
// test failure) if it cannot.
pid_t spawn(const std::vector<std::string>& argv, int out_fd, int err_fd,
            const std::vector<std::string>& environment = {});
// Waits for `pid` to exit until `deadline`: its exit status (128 + signal when killed), or -1
// if it is still running then.
int wait_exit(pid_t pid, std::chrono::steady_clock::time_point deadline);

// Runs a program to completion; kills it if it outlives `deadline` (by default 20 s, stretched
// by the build's slowdown like every upper bound on a wait: an ASan ioportctl scanning 72
// addresses with deadlines of its own stretched took longer).
Outcome run(const std::vector<std::string>& argv,
            std::chrono::milliseconds deadline = 20s * slowdown);

// A started program whose stdout can be waited on line by line; SIGTERM and reaped on destruction.
class Child {
  public:
    explicit Child(const std::vector<std::string>& argv);
    ~Child();
    Child(const Child&) = delete;
    Child& operator=(const Child&) = delete;

    // The next line of stdout, or "" if none came within `deadline`.
    std::string read_line(std::chrono::milliseconds deadline);
    // Sends `signal` and waits up to `deadline` for the exit status (-1 if it did not exit).
    int stop(int signal, std::chrono::milliseconds deadline);
    pid_t pid() const { return pid_; }

  private:
    pid_t pid_ = -1;
    int out_fd_ = -1;
    std::string buffered_;
};

// How many descriptors process `pid` has open (0 if /proc cannot tell).
std::size_t open_descriptors(pid_t pid);

// A temporary directory, removed with everything in it.
class TempDir {
  public:
    TempDir();
    ~TempDir();
    const std::filesystem::path& path() const { return path_; }
    std::string operator/(std::string_view name) const { return (path_ / name).string(); }

  private:
    std::filesystem::path path_;
};

// ioport-sim running in its own process, ready when constructed.
class SimProcess {
  public:
    // `device`: "--hub" with a module list, or "--id2" with "".
    SimProcess(const std::string& device_flag, const std::string& modules,
               std::vector<std::string> extra = {});
    const std::string& link() const { return link_; }
    // The control socket, for clients of its own (one per thread: ControlClient blocks).
    const std::string& control() const { return control_; }
    // Sends a control command; fails the test on an error reply.
    std::string ctl(std::string_view command);
    Result<std::string> try_ctl(std::string_view command);
    // The simulator's process: SIGSTOP and SIGCONT starve it as a busy machine does, exactly.
    pid_t pid() const { return child_.pid(); }

  private:
    TempDir dir_;
    std::string link_;
    std::string control_;
    Child child_;
    sim::ControlClient client_;
};

}  // namespace ioport::test
