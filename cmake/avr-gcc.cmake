# Toolchain file for the ATmega328P (Arduino Uno) with Debian's gcc-avr 5.4 and avr-libc.
# Usage: cmake -S . -B build-avr --toolchain cmake/avr-gcc.cmake
set(CMAKE_SYSTEM_NAME Generic)
set(CMAKE_SYSTEM_PROCESSOR avr)
set(CMAKE_C_COMPILER avr-gcc)
set(CMAKE_CXX_COMPILER avr-g++)
set(CMAKE_ASM_COMPILER avr-gcc)
set(CMAKE_OBJCOPY avr-objcopy CACHE FILEPATH "objcopy for AVR")
set(CMAKE_SIZE avr-size CACHE FILEPATH "size for AVR")
set(CMAKE_TRY_COMPILE_TARGET_TYPE STATIC_LIBRARY)

set(CDRO_AVR_MCU atmega328p CACHE STRING "AVR part")
set(CDRO_AVR_F_CPU 16000000UL CACHE STRING "CPU clock in Hz")

set(CMAKE_C_FLAGS_INIT "-mmcu=${CDRO_AVR_MCU} -DF_CPU=${CDRO_AVR_F_CPU} -ffunction-sections -fdata-sections")
set(CMAKE_CXX_FLAGS_INIT "-mmcu=${CDRO_AVR_MCU} -DF_CPU=${CDRO_AVR_F_CPU} -ffunction-sections -fdata-sections -fno-exceptions -fno-rtti -fno-threadsafe-statics")
set(CMAKE_EXE_LINKER_FLAGS_INIT "-mmcu=${CDRO_AVR_MCU} -Wl,--gc-sections")

set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
