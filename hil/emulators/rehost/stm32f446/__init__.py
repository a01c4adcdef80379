"""Models of the STM32F446 peripherals the NUCLEO-F446RE firmware touches (RM0390 rev 6).

Each model implements the registers and the fields the board's C (board_nucleo.c,
nucleo_*.c) uses and raises :class:`hil.emulators.rehost.machine.UnsupportedAccessError` for
anything else (another register, a mode it does not model, an access with the peripheral's
clock off). What each one does not model is listed in docs/firmware-emulated.md ("The
rehosted image").

One module per peripheral group: :mod:`.clocks` (PWR, RCC), :mod:`.flash` (the flash
interface and sectors 5-7), :mod:`.gpio` (GPIOA-C), :mod:`.usart_dma` (USART2, DMA1),
:mod:`.timers` (TIM5, TIM1, TIM3, TIM2), :mod:`.spi` (SPI2), :mod:`.iwdg` (IWDG) and
:mod:`.rng` (RNG). :mod:`hil.emulators.rehost.nucleo` wires them into the board.
"""
