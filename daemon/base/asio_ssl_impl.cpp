// Boost.Asio's SSL implementation, compiled once (BOOST_ASIO_SEPARATE_COMPILATION, as
// link/asio_impl.cpp does for the rest of Asio): the TLS listeners' (tls_server.hpp).
#include <utility>

#include <boost/asio/ssl/impl/src.hpp>
