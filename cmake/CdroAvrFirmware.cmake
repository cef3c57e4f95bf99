# The AVR firmware image: the Arduino core and Wire compiled from the system's arduino-core-avr
# (third-party code, its own relaxed flags), our core and binding with the project warnings, the
# .elf, the .hex, and a size check that fails the build when the budget is exceeded.
#
# Cache variables:
#   CDRO_AVR_BOARD              uno (ATmega328P, default) or mega (ATmega2560); set in the
#                               toolchain file, which picks the MCU from it
#   CDRO_ARDUINO_AVR_DIR        the arduino-core-avr tree (Debian: /usr/share/arduino/hardware/arduino/avr)
#   CDRO_FW_FLASH_BUDGET_BYTES  flash budget (.text + .data); Uno default 24576
#   CDRO_FW_RAM_BUDGET_BYTES    static RAM budget (.data + .bss + .noinit); Uno default 1228
#   CDRO_FW_SERIAL_TX_BUFFER    HardwareSerial transmit buffer, bytes (default 128)
#   CDRO_FW_SERIAL_RX_BUFFER    HardwareSerial receive buffer, bytes (default 64)
#   CDRO_UPLOAD_PORT            the board's serial port for `--target upload` (/dev/ttyACM0)
#   CDRO_UPLOAD_PROGRAMMER      avrdude programmer (Uno: arduino, Optiboot; Mega: wiring, stk500v2)
#   CDRO_UPLOAD_BAUD            the bootloader's bit/s (115200 for both)
#   CDRO_AVRDUDE                avrdude (Debian package avrdude; scripts/setup.sh installs it)

set(CDRO_ARDUINO_AVR_DIR /usr/share/arduino/hardware/arduino/avr CACHE PATH "arduino-core-avr tree")
set(CDRO_FW_SERIAL_TX_BUFFER 128 CACHE STRING "HardwareSerial TX buffer in bytes")
set(CDRO_FW_SERIAL_RX_BUFFER 64 CACHE STRING "HardwareSerial RX buffer in bytes")

if(CDRO_AVR_BOARD STREQUAL "mega")
  set(_variant mega)
  set(_board_define ARDUINO_AVR_MEGA2560)
  set(_flash_default 253952) # 256 KB minus the 8 KB bootloader section
  set(_ram_default 6144)     # of 8 KB, leaving 2 KB for the stack
  set(_max_nodes 20)
  set(_programmer wiring)    # the Mega's stk500v2 bootloader
elseif(CDRO_AVR_BOARD STREQUAL "uno")
  set(_variant standard)
  set(_board_define ARDUINO_AVR_UNO)
  set(_flash_default 24576)  # budget: 24 KB of the 32 KB (0.5 KB go to Optiboot)
  set(_ram_default 1228)     # budget: 1.2 KB of the 2 KB, the rest is stack
  set(_max_nodes 10)
  set(_programmer arduino)   # Optiboot
else()
  message(FATAL_ERROR "CDRO_AVR_BOARD must be uno or mega, not '${CDRO_AVR_BOARD}'")
endif()
set(CDRO_FW_FLASH_BUDGET_BYTES ${_flash_default} CACHE STRING "Firmware flash budget in bytes")
set(CDRO_FW_RAM_BUDGET_BYTES ${_ram_default} CACHE STRING "Firmware static RAM budget in bytes")
set(CDRO_UPLOAD_PORT /dev/ttyACM0 CACHE STRING "serial port of the board for --target upload")
set(CDRO_UPLOAD_PROGRAMMER ${_programmer} CACHE STRING "avrdude programmer for --target upload")
set(CDRO_UPLOAD_BAUD 115200 CACHE STRING "bootloader bit/s for --target upload")
find_program(CDRO_AVRDUDE avrdude)

function(cdro_avr_firmware)
  set(arduino ${CDRO_ARDUINO_AVR_DIR})
  if(NOT EXISTS ${arduino}/cores/arduino/Arduino.h)
    message(FATAL_ERROR "arduino-core-avr not found at ${arduino} (apt-get install arduino-core-avr)")
  endif()

  # --- the Arduino core and Wire: third-party, compiled in place, warnings off ---------------
  set(core ${arduino}/cores/arduino)
  set(wire ${arduino}/libraries/Wire/src)
  add_library(cdro_arduino_core STATIC
    ${core}/wiring.c ${core}/wiring_digital.c ${core}/hooks.c ${core}/WInterrupts.c
    ${core}/HardwareSerial.cpp ${core}/HardwareSerial0.cpp ${core}/Print.cpp ${core}/Stream.cpp
    ${core}/WString.cpp ${core}/abi.cpp ${core}/main.cpp
    ${wire}/Wire.cpp ${wire}/utility/twi.c)
  # Not SYSTEM: avr-gcc wraps system headers in extern "C", which breaks the C++ ones. The
  # binding silences their warnings with pragmas around the includes instead.
  target_include_directories(cdro_arduino_core PUBLIC
    ${core} ${arduino}/variants/${_variant} ${wire})
  target_compile_definitions(cdro_arduino_core PUBLIC
    ARDUINO=10807 ${_board_define} ARDUINO_ARCH_AVR
    SERIAL_TX_BUFFER_SIZE=${CDRO_FW_SERIAL_TX_BUFFER}
    SERIAL_RX_BUFFER_SIZE=${CDRO_FW_SERIAL_RX_BUFFER}
    PRIVATE DECIMAL_DIG=17) # WString.cpp needs it with Debian's avr-gcc 5.4
  target_compile_options(cdro_arduino_core PRIVATE -w -fpermissive)
  set_target_properties(cdro_arduino_core PROPERTIES
    C_STANDARD 11 C_EXTENSIONS ON CXX_STANDARD 11 CXX_EXTENSIONS ON)

  # --- our part ---------------------------------------------------------------------------------
  target_compile_definitions(cdro_fw_core PUBLIC CDRO_FW_MAX_REMOTE_NODES=${_max_nodes})
  set(image cdro-firmware-${CDRO_AVR_BOARD})
  add_executable(${image} ${CMAKE_CURRENT_SOURCE_DIR}/arduino/cdro_arduino.cpp)
  target_link_libraries(${image} PRIVATE cdro_fw_core cdro_common cdro_arduino_core)
  set_target_properties(${image} PROPERTIES SUFFIX ".elf" CXX_STANDARD 11 CXX_EXTENSIONS ON)
  cdro_target_warnings(${image})
  target_link_options(${image} PRIVATE -Wl,-Map=$<TARGET_FILE_DIR:${image}>/${image}.map)

  set(elf $<TARGET_FILE:${image}>)
  set(hex ${CMAKE_RUNTIME_OUTPUT_DIRECTORY}/${image}.hex)
  add_custom_command(OUTPUT ${hex}
    COMMAND ${CMAKE_OBJCOPY} -O ihex -R .eeprom ${elf} ${hex}
    DEPENDS ${image}
    COMMENT "${image}.hex")
  # Runs on every build (no output file), so every build prints the figures and every build
  # fails while the image is over its budget.
  add_custom_target(${image}-size ALL
    COMMAND ${CMAKE_COMMAND}
      -DELF=${elf} -DSIZE_TOOL=${CMAKE_SIZE} -DNM_TOOL=${CMAKE_NM}
      -DBOARD=${CDRO_AVR_BOARD} -DMCU=${CDRO_AVR_MCU}
      -DFLASH_BUDGET=${CDRO_FW_FLASH_BUDGET_BYTES} -DRAM_BUDGET=${CDRO_FW_RAM_BUDGET_BYTES}
      -P ${PROJECT_SOURCE_DIR}/cmake/CdroAvrSizeCheck.cmake
    DEPENDS ${hex}
    COMMENT "size budget of ${image}"
    VERBATIM)
  add_dependencies(${image}-size ${image})

  # `cmake --build build-avr --target upload`: the image, once within its budget, onto the
  # board through its bootloader. -D: no chip erase (the bootloader cannot do one).
  if(CDRO_AVRDUDE)
    add_custom_target(upload
      COMMAND ${CDRO_AVRDUDE} -p ${CDRO_AVR_MCU} -c ${CDRO_UPLOAD_PROGRAMMER} -P ${CDRO_UPLOAD_PORT}
              -b ${CDRO_UPLOAD_BAUD} -D -U flash:w:${hex}:i
      DEPENDS ${image}-size
      COMMENT "avrdude: ${image}.hex -> ${CDRO_UPLOAD_PORT} (${CDRO_UPLOAD_PROGRAMMER}, ${CDRO_UPLOAD_BAUD} bit/s)"
      USES_TERMINAL VERBATIM)
  else()
    add_custom_target(upload
      COMMAND ${CMAKE_COMMAND} -E echo "upload: avrdude not found (apt-get install avrdude, or scripts/setup.sh)"
      COMMAND ${CMAKE_COMMAND} -E false
      VERBATIM)
  endif()
endfunction()
