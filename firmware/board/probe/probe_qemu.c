/* What QEMU 7.2's netduinoplus2 (STM32F405) emulates: a tiny image that tries each
 * peripheral the rig firmware would use and reports on every USART (the one QEMU connects
 * to -serial is the one whose lines arrive). Run by firmware/board/probe/run_probe.py;
 * its findings are in docs/firmware-emulated.md. Not part of the rig firmware. */
#include <stdint.h>

#include "stm32f4_regs.h"

static usart_regs *const ports[6] = {USART1, USART2, USART3, UART4, UART5, USART6};
static volatile uint32_t systicks, tim5_irqs, rx_irqs, rx_last;

void SysTick_Handler(void) { systicks++; }

void TIM5_IRQHandler(void) {
    TIM5->SR = 0;
    tim5_irqs++;
}

void USART1_IRQHandler(void) {
    if (USART1->SR & USART_SR_RXNE) {
        rx_last = USART1->DR & 0xFFu;
        rx_irqs++;
    }
}
void USART2_IRQHandler(void) {
    if (USART2->SR & USART_SR_RXNE) {
        rx_last = USART2->DR & 0xFFu;
        rx_irqs++;
    }
}

static void put(usart_regs *u, const char *s) {
    while (*s) {
        while (!(u->SR & USART_SR_TXE)) {
        }
        u->DR = (uint8_t)*s++;
    }
}

static void out(const char *s) {
    for (unsigned i = 0; i < 6; i++) put(ports[i], s);
}

static void hex(uint32_t v) {
    char b[11] = "0x00000000";
    for (int i = 0; i < 8; i++) b[9 - i] = "0123456789abcdef"[(v >> (4 * i)) & 15u];
    out(b);
}

static void kv(const char *k, uint32_t v) {
    out(k);
    out("=");
    hex(v);
    out("\r\n");
}

int main(void) {
    for (unsigned i = 0; i < 6; i++) {
        ports[i]->CR1 = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE;
        put(ports[i], "probe: this is USART");
        char n[4] = {(char)('1' + i), '\r', '\n', 0};
        put(ports[i], n);
    }
    /* RCC: emulated? (HSE ready flag, PLL) */
    kv("RCC_CR", RCC->CR);
    RCC->CR |= RCC_CR_HSEON;
    kv("RCC_CR_after_HSEON", RCC->CR);
    RCC->AHB1ENR |= RCC_AHB1_GPIOA;
    kv("RCC_AHB1ENR", RCC->AHB1ENR);
    /* RNG */
    RCC->AHB2ENR |= RCC_AHB2_RNG;
    RNG->CR = RNG_CR_RNGEN;
    uint32_t n = 0;
    while (!(RNG->SR & RNG_SR_DRDY) && n < 100000u) n++;
    kv("RNG_SR", RNG->SR);
    kv("RNG_DR", RNG->DR);
    kv("RNG_DR2", RNG->DR);
    kv("RNG_polls", n);
    /* DWT cycle counter */
    REG32(0xE000EDFCu) |= 1u << 24; /* DEMCR.TRCENA */
    REG32(0xE0001000u) |= 1u;        /* DWT_CTRL.CYCCNTENA */
    uint32_t c0 = REG32(0xE0001004u);
    for (volatile int i = 0; i < 1000; i++) {
    }
    kv("DWT_CYCCNT_delta", REG32(0xE0001004u) - c0);
    /* timers */
    RCC->APB1ENR |= RCC_APB1_TIM2 | RCC_APB1_TIM5;
    RCC->APB2ENR |= RCC_APB2_TIM1;
    TIM2->PSC = 0;
    TIM2->ARR = 0xFFFFFFFFu;
    TIM2->CR1 = TIM_CR1_CEN;
    uint32_t t0 = TIM2->CNT;
    for (volatile int i = 0; i < 10000; i++) {
    }
    kv("TIM2_CNT_delta", TIM2->CNT - t0);
    TIM2->SMCR = TIM_SMCR_SMS_ENCODER3;
    kv("TIM2_SMCR_encoder", TIM2->SMCR);
    TIM1->PSC = 0;
    TIM1->ARR = 0xFFFFu;
    TIM1->RCR = 5;
    TIM1->CR1 = TIM_CR1_CEN;
    kv("TIM1_CNT", TIM1->CNT);
    kv("TIM1_RCR", TIM1->RCR);
    /* TIM5 at 1 kHz from the 84 MHz? timer clock: PSC 83 -> 1 MHz, ARR 999 */
    TIM5->PSC = 83;
    TIM5->ARR = 999;
    TIM5->EGR = TIM_EGR_UG;
    TIM5->SR = 0;
    TIM5->DIER = TIM_DIER_UIE;
    TIM5->CR1 = TIM_CR1_CEN;
    nvic_enable(IRQ_TIM5, 2);
    /* SysTick at 1 kHz of a 168 MHz processor clock */
    SYSTICK->LOAD = 168000u - 1u;
    SYSTICK->VAL = 0;
    SYSTICK->CTRL = SYSTICK_CTRL_ENABLE | SYSTICK_CTRL_TICKINT | SYSTICK_CTRL_CLKSOURCE;
    kv("SYST_CALIB", SYSTICK->CALIB);
    uint32_t v0 = SYSTICK->VAL, v1 = SYSTICK->VAL;
    kv("SYST_VAL0", v0);
    kv("SYST_VAL1", v1);
    /* IWDG */
    IWDG->KR = IWDG_KEY_UNLOCK;
    IWDG->PR = 2;
    kv("IWDG_PR", IWDG->PR);
    kv("IWDG_SR", IWDG->SR);
    /* RX interrupts on USART1 and USART2 */
    USART1->CR1 |= USART_CR1_RXNEIE;
    USART2->CR1 |= USART_CR1_RXNEIE;
    nvic_enable(IRQ_USART1, 1);
    nvic_enable(IRQ_USART2, 1);
    kv("SEED_WORD", REG32(0x20010000u));
    for (int i = 0; i < 3; i++) {
        uint32_t a = SYSTICK->VAL;
        for (volatile int k = 0; k < 100; k++) {
        }
        uint32_t b = SYSTICK->VAL;
        kv("SYST_VAL_a", a);
        kv("SYST_VAL_b", b);
    }
    out("READY\r\n");
    uint32_t last_rx = 0, reported = 0;
    for (;;) {
        if (systicks - reported >= 1000u) {
            reported += 1000u;
            out("S ");
            hex(systicks);
            out(" T5 ");
            hex(tim5_irqs);
            out("\r\n");
        }
        if (rx_irqs != last_rx) {
            last_rx = rx_irqs;
            out("RX ");
            hex(rx_last);
            out("\r\n");
        }
        wait_for_interrupt();
    }
}
