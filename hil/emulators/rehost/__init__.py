"""The NUCLEO-F446RE firmware image rehosted: run unchanged on the `unicorn` CPU emulator
with models of the STM32F446 peripherals it touches, joined to the simulated rig
(docs/firmware-emulated.md, "The rehosted image"). :mod:`hil.emulators.rehost.nucleo` is the
entry point."""
