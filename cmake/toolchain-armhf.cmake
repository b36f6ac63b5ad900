# Debian armhf (ARMv7-A with VFPv3-D16, hard float, Thumb-2): 32-bit ARM boards and 32-bit
# Raspberry Pi OS on a Pi 2 or later. Not ARMv6: a Raspberry Pi 1 or Zero runs neither Debian's
# armhf nor this. See debian-cross.cmake.
set(ioportd_deb_arch armhf)
set(ioportd_triplet arm-linux-gnueabihf)
set(ioportd_processor arm)
set(ioportd_qemu qemu-arm)
# g++ notes on every std::vector iterator passed by value that its ABI changed in GCC 7.1: news
# only for code built with GCC 6 or older, of which Debian 12 has none.
set(CMAKE_CXX_FLAGS_INIT -Wno-psabi)
include(${CMAKE_CURRENT_LIST_DIR}/debian-cross.cmake)
