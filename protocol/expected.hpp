// Expected<T, E>: a value or the error that prevented it.
//
// std::expected would do, but clang 14 (clang-tidy, libFuzzer) cannot compile libstdc++ 12's
// <expected>; this is the subset the project uses, on std::variant so that every compiler can.
#pragma once

#include <optional>
#include <stdexcept>
#include <type_traits>
#include <utility>
#include <variant>

namespace ioport {

template <class E>
class Unexpected {
  public:
    explicit Unexpected(E error) : error_(std::move(error)) {}
    const E& error() const& { return error_; }
    E&& error() && { return std::move(error_); }

  private:
    E error_;
};
template <class E>
Unexpected(E) -> Unexpected<E>;

template <class T, class E>
class Expected;

namespace detail {
template <class U>
inline constexpr bool is_expected_or_unexpected = false;
template <class T, class E>
inline constexpr bool is_expected_or_unexpected<Expected<T, E>> = true;
template <class E>
inline constexpr bool is_expected_or_unexpected<Unexpected<E>> = true;

// What value() throws when there is none: a programming error, the message says which.
[[noreturn]] inline void no_value(const auto& error) {
    if constexpr (requires { error.message; })
        throw std::logic_error("no value: " + error.message);
    else
        throw std::logic_error("no value");
}
}  // namespace detail

template <class T, class E>
class Expected {
  public:
    Expected() requires std::is_default_constructible_v<T> : state_(std::in_place_index<0>) {}
    template <class U = T>
    requires(std::is_constructible_v<T, U&&> &&
             !detail::is_expected_or_unexpected<std::remove_cvref_t<U>>)
        // NOLINTNEXTLINE(bugprone-forwarding-reference-overload): the constraint excludes Expected
        Expected(U&& value)
        : state_(std::in_place_index<0>, std::forward<U>(value)) {}
    template <class G>
    Expected(const Unexpected<G>& failure) : state_(std::in_place_index<1>, failure.error()) {}
    template <class G>
    Expected(Unexpected<G>&& failure)
        : state_(std::in_place_index<1>, std::move(failure).error()) {}

    bool has_value() const noexcept { return state_.index() == 0; }
    explicit operator bool() const noexcept { return has_value(); }

    T& operator*() & { return *std::get_if<0>(&state_); }
    const T& operator*() const& { return *std::get_if<0>(&state_); }
    T&& operator*() && { return std::move(*std::get_if<0>(&state_)); }
    T* operator->() { return std::get_if<0>(&state_); }
    const T* operator->() const { return std::get_if<0>(&state_); }

    T& value() & {
        if (!has_value()) detail::no_value(error());
        return **this;
    }
    const T& value() const& {
        if (!has_value()) detail::no_value(error());
        return **this;
    }
    T&& value() && { return std::move(value()); }
    template <class U>
    T value_or(U&& fallback) const& {
        return has_value() ? **this : static_cast<T>(std::forward<U>(fallback));
    }

    E& error() & { return *std::get_if<1>(&state_); }
    const E& error() const& { return *std::get_if<1>(&state_); }
    E&& error() && { return std::move(*std::get_if<1>(&state_)); }

    template <class U>
    requires(!detail::is_expected_or_unexpected<U>) friend bool operator==(const Expected& x,
                                                                           const U& value) {
        return x.has_value() && *x == value;
    }

  private:
    std::variant<T, E> state_;
};

template <class E>
class Expected<void, E> {
  public:
    Expected() = default;
    template <class G>
    Expected(const Unexpected<G>& failure) : error_(failure.error()) {}
    template <class G>
    Expected(Unexpected<G>&& failure) : error_(std::move(failure).error()) {}

    bool has_value() const noexcept { return !error_; }
    explicit operator bool() const noexcept { return has_value(); }
    void value() const {
        if (error_) detail::no_value(*error_);
    }

    E& error() & { return *error_; }
    const E& error() const& { return *error_; }
    E&& error() && { return std::move(*error_); }

  private:
    std::optional<E> error_;
};

}  // namespace ioport
