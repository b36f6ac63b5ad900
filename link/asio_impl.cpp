// Boost.Asio's out-of-line implementation, compiled once for the whole project
// (BOOST_ASIO_SEPARATE_COMPILATION): this keeps every other translation unit small.
#include <utility>

#include <boost/asio/impl/src.hpp>
