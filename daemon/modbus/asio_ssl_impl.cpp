// Boost.Asio's SSL implementation, compiled once (BOOST_ASIO_SEPARATE_COMPILATION, as
// link/asio_impl.cpp does for the rest of Asio): the Modbus/TCP Security listener's.
#include <utility>

#include <boost/asio/ssl/impl/src.hpp>
