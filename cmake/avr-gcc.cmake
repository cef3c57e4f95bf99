# Toolchain file for the Arduino boards (Uno: ATmega328P, Mega: ATmega2560) with Debian's gcc-avr 5.4 and avr-libc.
# Usage: cmake -S . -B build-avr --toolchain cmake/avr-gcc.cmake
set(CMAKE_SYSTEM_NAME Generic)
set(CMAKE_SYSTEM_PROCESSOR avr)
set(CMAKE_C_COMPILER avr-gcc)
set(CMAKE_CXX_COMPILER avr-g++)
set(CMAKE_ASM_COMPILER avr-gcc)
set(CMAKE_OBJCOPY avr-objcopy CACHE FILEPATH "objcopy for AVR")
set(CMAKE_SIZE avr-size CACHE FILEPATH "size for AVR")
set(CMAKE_NM avr-nm CACHE FILEPATH "nm for AVR")
set(CMAKE_TRY_COMPILE_TARGET_TYPE STATIC_LIBRARY)

# The board picks the part: uno (ATmega328P, default) or mega (ATmega2560).
#   cmake -S . -B build-avr-mega --toolchain cmake/avr-gcc.cmake -DCDRO_AVR_BOARD=mega
set(CDRO_AVR_BOARD uno CACHE STRING "Arduino board: uno or mega")
if(CDRO_AVR_BOARD STREQUAL "mega")
  set(CDRO_AVR_MCU atmega2560)
else()
  set(CDRO_AVR_MCU atmega328p)
endif()
list(APPEND CMAKE_TRY_COMPILE_PLATFORM_VARIABLES CDRO_AVR_BOARD)
set(CDRO_AVR_F_CPU 16000000UL CACHE STRING "CPU clock in Hz")

# Link-time optimisation, as the Arduino IDE and PlatformIO build AVR images (-flto): about 2 KB
# less flash for this image. Static libraries then need the plugin-aware archiver.
set(CMAKE_AR avr-gcc-ar CACHE FILEPATH "LTO-aware ar for AVR" FORCE)
set(CMAKE_RANLIB avr-gcc-ranlib CACHE FILEPATH "LTO-aware ranlib for AVR" FORCE)
set(CMAKE_C_FLAGS_INIT "-mmcu=${CDRO_AVR_MCU} -DF_CPU=${CDRO_AVR_F_CPU} -ffunction-sections -fdata-sections -flto")
set(CMAKE_CXX_FLAGS_INIT "-mmcu=${CDRO_AVR_MCU} -DF_CPU=${CDRO_AVR_F_CPU} -ffunction-sections -fdata-sections -flto -fno-exceptions -fno-rtti -fno-threadsafe-statics")
set(CMAKE_EXE_LINKER_FLAGS_INIT "-mmcu=${CDRO_AVR_MCU} -Wl,--gc-sections -flto -fuse-linker-plugin")

set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
