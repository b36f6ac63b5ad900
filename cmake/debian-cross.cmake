# A cross build for a Debian architecture: Debian's cross compiler (crossbuild-essential-ARCH),
# and the libraries from a sysroot of that architecture's -dev packages, which
# scripts/package makes with mmdebstrap (docs/development.md, "Packages for ARM"). Included by
# toolchain-ARCH.cmake, which sets ioportd_deb_arch (Debian's name), ioportd_triplet (the GNU
# multiarch triplet), ioportd_processor and ioportd_qemu (qemu-user's program for it).
#
#   cmake -S . -B build-arm64 -DCMAKE_TOOLCHAIN_FILE=cmake/toolchain-arm64.cmake \
#         -DCMAKE_SYSROOT=/path/to/sysroot -DCMAKE_BUILD_TYPE=Release
if(NOT CMAKE_SYSROOT)
  message(FATAL_ERROR "A cross build for ${ioportd_deb_arch} needs CMAKE_SYSROOT: a directory "
    "holding ${ioportd_deb_arch}'s -dev packages (scripts/package --arch ${ioportd_deb_arch} "
    "makes one and configures the build with it)")
endif()

set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR ${ioportd_processor})
set(CMAKE_LIBRARY_ARCHITECTURE ${ioportd_triplet})
set(CMAKE_C_COMPILER ${ioportd_triplet}-gcc)
set(CMAKE_CXX_COMPILER ${ioportd_triplet}-g++)

# Headers, libraries and CMake packages from the sysroot only; programs (protoc) from the build
# machine. The compiler finds its own C and C++ runtime first, the sysroot's after it, as
# Debian's cross compilers do with multiarch -dev packages.
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)
# pkg-config reads the sysroot's multiarch directory and prefixes what it prints with it.
set(ENV{PKG_CONFIG_SYSROOT_DIR} ${CMAKE_SYSROOT})
set(ENV{PKG_CONFIG_LIBDIR}
  "${CMAKE_SYSROOT}/usr/lib/${ioportd_triplet}/pkgconfig:${CMAKE_SYSROOT}/usr/share/pkgconfig")

# ctest runs the target's programs under qemu-user, with the sysroot's dynamic loader and
# libraries (tests/CMakeLists.txt: the integration tests start ioportd and ioportctl so too).
set(CMAKE_CROSSCOMPILING_EMULATOR ${ioportd_qemu} -L ${CMAKE_SYSROOT})

# The package's Architecture: field (packaging/CMakeLists.txt).
set(IOPORTD_DEB_ARCH ${ioportd_deb_arch})
