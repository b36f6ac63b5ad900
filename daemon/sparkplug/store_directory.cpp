#include "daemon/sparkplug/store_directory.hpp"

#include <dirent.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <system_error>

#include <fmt/format.h>

namespace ioport::daemon {
namespace {

namespace fs = std::filesystem;

std::string error_text(int error) {
    return std::generic_category().message(error);
}

// Of the directory itself, as open() and check_store_directory() find it.
Result<> check_directory(const fs::path& dir, const struct stat& st) {
    if (!S_ISDIR(st.st_mode))
        return fail(Errc::invalid_argument,
                    fmt::format("mqtt.store.path: {} is not a directory", dir.string()));
    if (st.st_uid != ::geteuid())
        return fail(Errc::permission_denied,
                    fmt::format("mqtt.store.path: {} belongs to user id {}, not to the user "
                                "ioportd runs as (id {}): whoever owns it can plant links in it "
                                "to files ioportd would overwrite; give it to ioportd's user "
                                "(chown) or choose a directory of ioportd's own",
                                dir.string(), st.st_uid, ::geteuid()));
    if ((st.st_mode & (S_IWGRP | S_IWOTH)) != 0)
        return fail(Errc::permission_denied,
                    fmt::format("mqtt.store.path: {} is writable by {} (mode {:04o}): others "
                                "could plant links in it to files ioportd would overwrite; "
                                "chmod go-w {} or choose a directory of ioportd's own",
                                dir.string(), (st.st_mode & S_IWOTH) != 0 ? "others" : "its group",
                                st.st_mode & 07777, dir.string()));
    return {};
}

}  // namespace

Result<> check_store_directory(const fs::path& dir) {
    struct stat st {};
    if (::stat(dir.c_str(), &st) != 0) {
        if (errno == ENOENT) return {};
        return fail(Errc::io_error,
                    fmt::format("store: cannot stat {}: {}", dir.string(), error_text(errno)));
    }
    return check_directory(dir, st);
}

Result<std::unique_ptr<DiskDirectory>> DiskDirectory::open(const fs::path& dir) {
    if (::mkdir(dir.c_str(), 0750) != 0 && errno != EEXIST)
        return fail(Errc::io_error,
                    fmt::format("store: cannot create {}: {}", dir.string(), error_text(errno)));
    // The configured path may pass through links (systemd's StateDirectory= with DynamicUser= is
    // one); what is checked is the directory it leads to, on the descriptor every later call uses.
    const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (fd < 0)
        return fail(Errc::io_error, fmt::format("store: cannot open the directory {}: {}",
                                                dir.string(), error_text(errno)));
    struct stat st {};
    if (::fstat(fd, &st) != 0) {
        const int error = errno;
        ::close(fd);
        return fail(Errc::io_error,
                    fmt::format("store: cannot stat {}: {}", dir.string(), error_text(error)));
    }
    if (auto checked = check_directory(dir, st); !checked) {
        ::close(fd);
        return Unexpected(checked.error());
    }
    return std::unique_ptr<DiskDirectory>(new DiskDirectory(dir, fd));
}

DiskDirectory::~DiskDirectory() {
    for (const auto& [file, name] : open_)
        ::close(file);
    ::close(fd_);
}

Unexpected<Error> DiskDirectory::failed(std::string_view what, std::string_view name,
                                        int error) const {
    return fail(
        error == ENOSPC || error == EDQUOT ? Errc::no_space : Errc::io_error,
        fmt::format("store: cannot {} {}: {}", what, (path_ / name).string(), error_text(error)));
}

Result<std::vector<std::string>> DiskDirectory::names() {
    const int listing = ::dup(fd_);
    if (listing < 0) return failed("list", "", errno);
    DIR* dir = ::fdopendir(listing);
    if (dir == nullptr) {
        const int error = errno;
        ::close(listing);
        return failed("list", "", error);
    }
    ::rewinddir(dir);  // the duplicate shares its position with fd_
    std::vector<std::string> found;
    errno = 0;
    while (const dirent* entry = ::readdir(dir)) {
        const std::string_view name = entry->d_name;
        if (name != "." && name != "..") found.emplace_back(name);
    }
    const int error = errno;
    ::closedir(dir);
    if (error != 0) return failed("list", "", error);
    return found;
}

Result<std::vector<std::uint8_t>> DiskDirectory::read(std::string_view name, std::uint64_t limit) {
    const std::string file(name);
    // O_NONBLOCK: a FIFO planted under a segment's name must not block the open.
    const int fd = ::openat(fd_, file.c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) return failed("open", name, errno);
    std::vector<std::uint8_t> bytes;
    struct stat st {};
    int error = ::fstat(fd, &st) != 0 ? errno : S_ISREG(st.st_mode) ? 0 : EINVAL;
    // Read straight into a buffer of the file's size: a segment is megabytes, and every copy or
    // regrowth of it costs the opening of a large store.
    // At most `limit`, a segment's few MiB and a record: a size_t on every architecture.
    if (error == 0)
        bytes.resize(static_cast<std::size_t>(
            std::min<std::uint64_t>(limit, static_cast<std::uint64_t>(st.st_size))));
    std::size_t got = 0;
    while (error == 0 && got < bytes.size()) {
        const auto n = ::read(fd, bytes.data() + got, bytes.size() - got);
        if (n < 0 && errno == EINTR) continue;
        if (n < 0) error = errno;
        if (n <= 0) break;
        got += static_cast<std::size_t>(n);
    }
    bytes.resize(got);
    ::close(fd);
    if (error != 0) return failed("read", name, error);
    return bytes;
}

Result<std::uint64_t> DiskDirectory::size(std::string_view name) {
    struct stat st {};
    if (::fstatat(fd_, std::string(name).c_str(), &st, AT_SYMLINK_NOFOLLOW) != 0)
        return failed("stat", name, errno);
    if (!S_ISREG(st.st_mode)) return failed("stat", name, EINVAL);
    return static_cast<std::uint64_t>(st.st_size);
}

Result<StoreDirectory::File> DiskDirectory::open_append(std::string_view name, bool create) {
    const std::string file(name);
    int flags = O_WRONLY | O_APPEND | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC;
    if (create) {
        if (auto removed = remove(name); !removed) return Unexpected(removed.error());
        flags |= O_CREAT | O_EXCL;
    }
    const int fd = ::openat(fd_, file.c_str(), flags, 0640);
    if (fd < 0) return failed(create ? "create" : "open", name, errno);
    struct stat st {};
    const int error = ::fstat(fd, &st) != 0 ? errno : S_ISREG(st.st_mode) ? 0 : EINVAL;
    if (error != 0) {
        ::close(fd);
        return failed("open", name, error);
    }
    open_.emplace_back(fd, file);
    return fd;
}

Result<> DiskDirectory::write(File file, std::span<const std::uint8_t> bytes) {
    while (!bytes.empty()) {
        const auto n = ::write(file, bytes.data(), bytes.size());
        if (n < 0 && errno == EINTR) continue;
        if (n < 0) return failed("write", name_of(file), errno);
        bytes = bytes.subspan(static_cast<std::size_t>(n));
    }
    return {};
}

Result<> DiskDirectory::truncate(File file, std::uint64_t size) {
    if (::ftruncate(file, static_cast<off_t>(size)) != 0)
        return failed("truncate", name_of(file), errno);
    return {};
}

Result<> DiskDirectory::sync(File file) {
    if (::fdatasync(file) != 0) return failed("sync", name_of(file), errno);
    return {};
}

void DiskDirectory::close(File file) {
    std::erase_if(open_, [file](const auto& entry) { return entry.first == file; });
    ::close(file);
}

Result<> DiskDirectory::rename(std::string_view from, std::string_view to) {
    if (::renameat(fd_, std::string(from).c_str(), fd_, std::string(to).c_str()) != 0)
        return failed("rename", from, errno);
    return {};
}

Result<> DiskDirectory::remove(std::string_view name) {
    if (::unlinkat(fd_, std::string(name).c_str(), 0) != 0 && errno != ENOENT)
        return failed("remove", name, errno);
    return {};
}

Result<> DiskDirectory::sync_names() {
    if (::fsync(fd_) != 0) return failed("sync the directory", "", errno);
    return {};
}

std::string_view DiskDirectory::name_of(File file) const {
    const auto found = std::ranges::find(open_, file, &std::pair<File, std::string>::first);
    return found == open_.end() ? std::string_view("?") : std::string_view(found->second);
}

}  // namespace ioport::daemon
