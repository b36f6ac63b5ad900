// The file operations of the Sparkplug store (gateway.md §6.2), within its one directory, and
// nothing else: StoreFiles makes every call through this interface. DiskDirectory is the real
// one; a test can put another behind StoreFiles to fail a call (a full disk) or to record every
// operation and build what a power cut at any point would leave.
//
// Names, never paths: every file is opened relative to the directory's descriptor, taken once,
// with O_NOFOLLOW, so a name cannot be made to lead anywhere else (a symlink planted in the
// directory, a directory renamed under it).
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "protocol/error.hpp"

namespace ioport::daemon {

class StoreDirectory {
  public:
    using File = int;  // a handle of the directory's, valid until close()

    virtual ~StoreDirectory() = default;

    // What the directory holds (names of regular files and anything else, "." and ".." aside).
    virtual Result<std::vector<std::string>> names() = 0;
    // At most `limit` bytes from the start of a regular file.
    virtual Result<std::vector<std::uint8_t>> read(std::string_view name, std::uint64_t limit) = 0;
    // The size of a regular file.
    virtual Result<std::uint64_t> size(std::string_view name) = 0;
    // A regular file opened for appending; `create`: a new, empty file, where whatever had the
    // name before (a file, a link planted there) is removed first, never followed.
    virtual Result<File> open_append(std::string_view name, bool create) = 0;
    // Writes all of `bytes` at the end, or fails; what a failed write left is the caller's to cut.
    virtual Result<> write(File file, std::span<const std::uint8_t> bytes) = 0;
    // Cuts the file to `size` bytes.
    virtual Result<> truncate(File file, std::uint64_t size) = 0;
    // Makes what was written to the file durable (fdatasync).
    virtual Result<> sync(File file) = 0;
    virtual void close(File file) = 0;
    // Replaces `to` with `from`, atomically.
    virtual Result<> rename(std::string_view from, std::string_view to) = 0;
    // Removes a name; a name already gone is no error.
    virtual Result<> remove(std::string_view name) = 0;
    // Makes the names made, renamed and removed so far durable (fsync of the directory).
    virtual Result<> sync_names() = 0;
    // For messages: the directory as configured.
    virtual const std::filesystem::path& path() const = 0;
};

// The store's directory on disk. open() creates it when missing (mode 0750) and refuses one
// that another user could write into: not owned by this process's user, writable by group or
// others, or not a directory (gateway.md §5.6's rule for files that grant rights, extended to the
// store's directory), saying which and what to do.
class DiskDirectory final : public StoreDirectory {
  public:
    static Result<std::unique_ptr<DiskDirectory>> open(const std::filesystem::path& dir);
    ~DiskDirectory() override;
    DiskDirectory(const DiskDirectory&) = delete;
    DiskDirectory& operator=(const DiskDirectory&) = delete;

    Result<std::vector<std::string>> names() override;
    Result<std::vector<std::uint8_t>> read(std::string_view name, std::uint64_t limit) override;
    Result<std::uint64_t> size(std::string_view name) override;
    Result<File> open_append(std::string_view name, bool create) override;
    Result<> write(File file, std::span<const std::uint8_t> bytes) override;
    Result<> truncate(File file, std::uint64_t size) override;
    Result<> sync(File file) override;
    void close(File file) override;
    Result<> rename(std::string_view from, std::string_view to) override;
    Result<> remove(std::string_view name) override;
    Result<> sync_names() override;
    const std::filesystem::path& path() const override { return path_; }

  private:
    DiskDirectory(std::filesystem::path path, int fd) : path_(std::move(path)), fd_(fd) {}
    Unexpected<Error> failed(std::string_view what, std::string_view name, int error) const;
    std::string_view name_of(File file) const;

    std::filesystem::path path_;
    int fd_;
    std::vector<std::pair<File, std::string>> open_;  // for messages: each open file's name
};

// The check DiskDirectory::open() makes, without creating anything: for a reload to refuse a
// directory before it changes what runs. A directory that does not exist yet passes.
Result<> check_store_directory(const std::filesystem::path& dir);

}  // namespace ioport::daemon
