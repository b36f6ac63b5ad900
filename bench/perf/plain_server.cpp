// plain-modbus-server [PORT]: the reference of benchmark 4 (bench/README.md). The textbook
// libmodbus 3.1.6 server: one thread, select() over every connection, modbus_receive() and
// modbus_reply() on one mapping as large as an ioportd unit's. No device, no validation: every
// read is answered from memory and every write only changes the mapping. Port 0 picks a free
// port; the one bound is printed as "listening on port N".
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstdlib>

#include <modbus/modbus.h>

int main(int argc, char** argv) {
    const int port = argc > 1 ? std::atoi(argv[1]) : 1502;
    modbus_t* context = modbus_new_tcp("127.0.0.1", port);
    modbus_mapping_t* mapping = modbus_mapping_new(128, 1072, 24, 1272);
    const int listener =
        context != nullptr && mapping != nullptr ? modbus_tcp_listen(context, 1024) : -1;
    if (listener < 0) return 1;
    sockaddr_in bound{};
    socklen_t length = sizeof bound;
    ::getsockname(listener, reinterpret_cast<sockaddr*>(&bound), &length);
    std::printf("listening on port %d\n", ntohs(bound.sin_port));
    (void)std::fflush(stdout);

    fd_set connections;
    FD_ZERO(&connections);
    FD_SET(listener, &connections);
    int highest = listener;
    std::uint8_t request[MODBUS_TCP_MAX_ADU_LENGTH];
    for (;;) {
        fd_set ready = connections;
        if (::select(highest + 1, &ready, nullptr, nullptr, nullptr) < 0) {
            if (errno == EINTR) continue;
            return 1;
        }
        for (int fd = 0; fd <= highest; ++fd) {
            if (!FD_ISSET(fd, &ready)) continue;
            if (fd == listener) {
                const int client = ::accept(listener, nullptr, nullptr);
                if (client < 0 || client >= FD_SETSIZE) {
                    if (client >= 0) ::close(client);
                    continue;
                }
                // As ioportd does: a response is never held back by Nagle's algorithm.
                const int on = 1;
                ::setsockopt(client, IPPROTO_TCP, TCP_NODELAY, &on, sizeof on);
                FD_SET(client, &connections);
                highest = std::max(highest, client);
                continue;
            }
            modbus_set_socket(context, fd);
            const int received = modbus_receive(context, request);
            if (received > 0) {
                modbus_reply(context, request, received, mapping);
            } else if (received == -1) {
                ::close(fd);
                FD_CLR(fd, &connections);
            }
        }
    }
}
