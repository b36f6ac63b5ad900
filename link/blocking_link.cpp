#include "link/blocking_link.hpp"

namespace ioport {

Result<Reading> BlockingLink::transact(const Exchange& exchange) {
    std::optional<Result<Reading>> outcome;
    asio::co_spawn(io_, link_.transact(exchange),
                   [&outcome](const std::exception_ptr& failure, Result<Reading> reading) {
                       if (failure)
                           outcome = fail(Errc::io_error, "internal error in the serial link");
                       else
                           outcome = std::move(reading);
                   });
    io_.restart();
    io_.run();
    return std::move(*outcome);
}

}  // namespace ioport
