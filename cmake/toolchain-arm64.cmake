# Debian arm64 (ARMv8-A, 64-bit): Raspberry Pi 3 and later, Revolution Pi, IOT2050, most ARM
# gateways. See debian-cross.cmake.
set(ioportd_deb_arch arm64)
set(ioportd_triplet aarch64-linux-gnu)
set(ioportd_processor aarch64)
set(ioportd_qemu qemu-aarch64)
include(${CMAKE_CURRENT_LIST_DIR}/debian-cross.cmake)
