"""Firmware in the loop: the board firmware (firmware/) built for the ATmega2560 and run in
simavr, with the project's plant as its robot. See docs/firmware.md."""
