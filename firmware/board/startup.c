/* Startup of both targets (STM32F446RE and STM32F405 under QEMU): the vector table, the
 * reset handler (FPU on, .data copied from flash, .bss zeroed, then main) and the default
 * handlers. Written for this project; the symbols come from the linker scripts here.
 *
 * Every handler is a weak alias of Default_Handler, so a board defines only those it uses.
 * Default_Handler and the fault handlers first call board_fault_stop() (the board's: the
 * driver's enable low, the step timer stopped; weak and empty here), then spin: the
 * independent watchdog (armed on the F446) then resets the MCU, which the host sees as a
 * new boot id.
 */
#include <stdint.h>

#include "stm32f4_regs.h"

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;
int main(void);
void Reset_Handler(void);
void Default_Handler(void);
void board_fault_stop(void);

#define WEAK_ALIAS __attribute__((weak, alias("Default_Handler")))
void NMI_Handler(void) WEAK_ALIAS;
void HardFault_Handler(void) WEAK_ALIAS;
void MemManage_Handler(void) WEAK_ALIAS;
void BusFault_Handler(void) WEAK_ALIAS;
void UsageFault_Handler(void) WEAK_ALIAS;
void SVC_Handler(void) WEAK_ALIAS;
void DebugMon_Handler(void) WEAK_ALIAS;
void PendSV_Handler(void) WEAK_ALIAS;
void SysTick_Handler(void) WEAK_ALIAS;
void DMA1_Stream6_IRQHandler(void) WEAK_ALIAS;
void TIM1_UP_TIM10_IRQHandler(void) WEAK_ALIAS;
void USART1_IRQHandler(void) WEAK_ALIAS;
void USART2_IRQHandler(void) WEAK_ALIAS;
void TIM5_IRQHandler(void) WEAK_ALIAS;

typedef void (*vector)(void);

/* 16 system exceptions (7-10 and 13 reserved) and the F446's 97 interrupts, every one
 * that this firmware does not use on Default_Handler. The F405 has 82: the entries past
 * its last interrupt are never taken. */
#define D Default_Handler
__attribute__((section(".isr_vector"), used))
const vector vector_table[16 + IRQ_COUNT_F446] = {
    (vector)(uintptr_t)&_estack, /* 0 */
    Reset_Handler, /* 1 */
    NMI_Handler, /* 2 */
    HardFault_Handler, /* 3 */
    MemManage_Handler, /* 4 */
    BusFault_Handler, /* 5 */
    UsageFault_Handler, /* 6 */
    0, /* 7 */
    0, /* 8 */
    0, /* 9 */
    0, /* 10 */
    SVC_Handler, /* 11 */
    DebugMon_Handler, /* 12 */
    0, /* 13 */
    PendSV_Handler, /* 14 */
    SysTick_Handler, /* 15 */
    D, D, D, D, D, D, D, D,
    D, D, D, D, D, D, D, D,
    D,
    DMA1_Stream6_IRQHandler, /* IRQ 17 */
    D, D, D, D, D, D, D,
    TIM1_UP_TIM10_IRQHandler, /* IRQ 25 */
    D, D, D, D, D, D, D, D,
    D, D, D,
    USART1_IRQHandler, /* IRQ 37 */
    USART2_IRQHandler, /* IRQ 38 */
    D, D, D, D, D, D, D, D,
    D, D, D,
    TIM5_IRQHandler, /* IRQ 50 */
    D, D, D, D, D, D, D, D,
    D, D, D, D, D, D, D, D,
    D, D, D, D, D, D, D, D,
    D, D, D, D, D, D, D, D,
    D, D, D, D, D, D, D, D,
    D, D, D, D, D, D,
};
#undef D

/* The board's safe state for a fault handler (nucleo_step.c); none on QEMU. */
__attribute__((weak)) void board_fault_stop(void) {}

void Default_Handler(void) {
    board_fault_stop();
    for (;;) {
    }
}

__attribute__((noreturn)) void Reset_Handler(void) {
    /* CP10 and CP11 full access: the FPU, before any floating-point instruction */
    SCB_CPACR |= 0xFu << 20;
    __asm volatile("dsb\n\tisb" ::: "memory");
    const uint32_t *src = &_sidata;
    for (uint32_t *dst = &_sdata; dst < &_edata;) *dst++ = *src++;
    for (uint32_t *dst = &_sbss; dst < &_ebss;) *dst++ = 0u;
    (void)main();
    for (;;) {
    }
}
