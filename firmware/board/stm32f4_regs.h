/* The STM32F4 registers this firmware uses, and nothing more: written from the reference
 * manuals (RM0390 for the F446, RM0090 for the F405) and the Cortex-M4 generic user guide.
 * No vendor header. Peripherals are structs of volatile 32-bit registers at their bus
 * addresses; reserved words are padding. Both targets share the F4 map below (the F405 and
 * the F446 place these peripherals at the same addresses).
 */
#ifndef STM32F4_REGS_H
#define STM32F4_REGS_H

#include <stdint.h>

#define REG32(addr) (*(volatile uint32_t *)(uintptr_t)(addr))

/* ---- Cortex-M4 core peripherals -------------------------------------------------------- */

typedef struct {
    volatile uint32_t CTRL, LOAD, VAL, CALIB;
} systick_regs;
#define SYSTICK ((systick_regs *)0xE000E010u)
#define SYSTICK_CTRL_ENABLE (1u << 0)
#define SYSTICK_CTRL_TICKINT (1u << 1)
#define SYSTICK_CTRL_CLKSOURCE (1u << 2) /* 1: processor clock, 0: external (HCLK/8) */
#define SYSTICK_CTRL_COUNTFLAG (1u << 16)

/* NVIC: set-enable, clear-enable, set-pending, clear-pending, priority bytes. */
#define NVIC_ISER(n) REG32(0xE000E100u + 4u * (n))
#define NVIC_ICER(n) REG32(0xE000E180u + 4u * (n))
#define NVIC_ICPR(n) REG32(0xE000E280u + 4u * (n))
#define NVIC_IPR8(irq) (*(volatile uint8_t *)(uintptr_t)(0xE000E400u + (irq)))

static inline void nvic_enable(unsigned irq, uint8_t prio) {
    NVIC_IPR8(irq) = (uint8_t)(prio << 4); /* 4 priority bits on the STM32F4 */
    NVIC_ICPR(irq >> 5) = 1u << (irq & 31u);
    NVIC_ISER(irq >> 5) = 1u << (irq & 31u);
}

/* DWT cycle counter (real silicon only: QEMU 7.2 reads 0) */
#define DEMCR REG32(0xE000EDFCu)
#define DEMCR_TRCENA (1u << 24)
#define DWT_CTRL REG32(0xE0001000u)
#define DWT_CTRL_CYCCNTENA 1u
#define DWT_CYCCNT REG32(0xE0001004u)

/* DBGMCU (RM0390 33.16): what stops while a debugger halts the core */
#define DBGMCU_APB1_FZ REG32(0xE0042008u)
#define DBGMCU_APB2_FZ REG32(0xE004200Cu)
#define DBGMCU_APB1_TIM2 (1u << 0)
#define DBGMCU_APB1_TIM3 (1u << 1)
#define DBGMCU_APB1_TIM5 (1u << 3)
#define DBGMCU_APB1_IWDG (1u << 12)
#define DBGMCU_APB2_TIM1 (1u << 0)

#define SCB_CPACR REG32(0xE000ED88u) /* coprocessor access: CP10/CP11 = FPU */
#define SCB_VTOR REG32(0xE000ED08u)
#define SCB_AIRCR REG32(0xE000ED0Cu)
#define SCB_SHPR3 REG32(0xE000ED20u) /* priorities of PendSV (bits 23:16), SysTick (31:24) */

/* IRQ numbers (position in the vector table after the 16 system exceptions). */
enum {
    IRQ_DMA1_STREAM6 = 17,
    IRQ_TIM1_UP_TIM10 = 25,
    IRQ_USART1 = 37,
    IRQ_USART2 = 38,
    IRQ_TIM5 = 50,
    IRQ_COUNT_F446 = 97
};

/* ---- RCC -------------------------------------------------------------------------------- */

typedef struct {
    volatile uint32_t CR, PLLCFGR, CFGR, CIR;
    volatile uint32_t AHB1RSTR, AHB2RSTR, AHB3RSTR, reserved0;
    volatile uint32_t APB1RSTR, APB2RSTR, reserved1[2];
    volatile uint32_t AHB1ENR, AHB2ENR, AHB3ENR, reserved2;
    volatile uint32_t APB1ENR, APB2ENR, reserved3[2];
    volatile uint32_t AHB1LPENR, AHB2LPENR, AHB3LPENR, reserved4;
    volatile uint32_t APB1LPENR, APB2LPENR, reserved5[2];
    volatile uint32_t BDCR, CSR, reserved6[2];
    volatile uint32_t SSCGR, PLLI2SCFGR, PLLSAICFGR, DCKCFGR;
    volatile uint32_t CKGATENR, DCKCFGR2; /* F446 only */
} rcc_regs;
#define RCC ((rcc_regs *)0x40023800u)

#define RCC_CR_HSEON (1u << 16)
#define RCC_CR_HSERDY (1u << 17)
#define RCC_CR_HSEBYP (1u << 18)
#define RCC_CR_PLLON (1u << 24)
#define RCC_CR_PLLRDY (1u << 25)
#define RCC_PLLCFGR_SRC_HSE (1u << 22)
#define RCC_CR_HSION (1u << 0)
#define RCC_CR_HSIRDY (1u << 1)
#define RCC_PLLCFGR(m, n, p, q, r) ((uint32_t)(m) | ((uint32_t)(n) << 6) | \
                                    ((((uint32_t)(p) / 2u) - 1u) << 16) | ((uint32_t)(q) << 24) | \
                                    ((uint32_t)(r) << 28))
#define RCC_CFGR_SW_HSI 0u
#define RCC_CFGR_SW_PLL 2u
#define RCC_CFGR_SWS_MASK (3u << 2)
#define RCC_CFGR_SWS_PLL (2u << 2)
#define RCC_CFGR_PPRE1_DIV4 (5u << 10)
#define RCC_CFGR_PPRE2_DIV2 (4u << 13)
#define RCC_CFGR_MCO2_HSE (2u << 30)   /* MCO2 (PC9) = HSE, prescaler bits 29:27 = 0 (/1) */
#define RCC_CSR_LSION (1u << 0)
#define RCC_CSR_LSIRDY (1u << 1)
#define RCC_CSR_RMVF (1u << 24)
#define RCC_CSR_IWDGRSTF (1u << 29)

/* enable bits */
#define RCC_AHB1_GPIOA (1u << 0)
#define RCC_AHB1_GPIOB (1u << 1)
#define RCC_AHB1_GPIOC (1u << 2)
#define RCC_AHB1_DMA1 (1u << 21)
#define RCC_AHB2_RNG (1u << 6)
#define RCC_APB1_TIM2 (1u << 0)
#define RCC_APB1_TIM3 (1u << 1)
#define RCC_APB1_TIM5 (1u << 3)
#define RCC_APB1_SPI2 (1u << 14)
#define RCC_APB1_USART2 (1u << 17)
#define RCC_APB1_PWR (1u << 28)
#define RCC_APB2_TIM1 (1u << 0)
#define RCC_APB2_USART1 (1u << 4)

/* ---- PWR (voltage scaling and over-drive, needed for 180 MHz) --------------------------- */

typedef struct {
    volatile uint32_t CR, CSR;
} pwr_regs;
#define PWR ((pwr_regs *)0x40007000u)
#define PWR_CR_VOS_SCALE1 (3u << 14)
#define PWR_CR_ODEN (1u << 16)
#define PWR_CR_ODSWEN (1u << 17)
#define PWR_CSR_ODRDY (1u << 16)
#define PWR_CSR_ODSWRDY (1u << 17)

/* ---- FLASH interface -------------------------------------------------------------------- */

typedef struct {
    volatile uint32_t ACR, KEYR, OPTKEYR, SR, CR, OPTCR;
} flash_regs;
#define FLASH ((flash_regs *)0x40023C00u)
#define FLASH_ACR_LATENCY(ws) ((uint32_t)(ws))
#define FLASH_ACR_PRFTEN (1u << 8)
#define FLASH_ACR_ICEN (1u << 9)
#define FLASH_ACR_DCEN (1u << 10)
#define FLASH_KEY1 0x45670123u
#define FLASH_KEY2 0xCDEF89ABu
#define FLASH_SR_BSY (1u << 16)
#define FLASH_SR_ERRORS 0xF2u /* OPERR, WRPERR, PGAERR, PGPERR, PGSERR (write 1 to clear) */
#define FLASH_CR_PG (1u << 0)
#define FLASH_CR_SER (1u << 1)
#define FLASH_CR_SNB(n) ((uint32_t)(n) << 3)
#define FLASH_CR_PSIZE_X32 (2u << 8)
#define FLASH_CR_STRT (1u << 16)
#define FLASH_CR_LOCK (1u << 31)

/* ---- GPIO ------------------------------------------------------------------------------- */

typedef struct {
    volatile uint32_t MODER, OTYPER, OSPEEDR, PUPDR, IDR, ODR, BSRR, LCKR, AFR[2];
} gpio_regs;
#define GPIOA ((gpio_regs *)0x40020000u)
#define GPIOB ((gpio_regs *)0x40020400u)
#define GPIOC ((gpio_regs *)0x40020800u)
#define GPIO_MODE_INPUT 0u
#define GPIO_MODE_OUTPUT 1u
#define GPIO_MODE_AF 2u
#define GPIO_PULL_NONE 0u
#define GPIO_PULL_UP 1u
#define GPIO_PULL_DOWN 2u

/* ---- USART (F4 "v1" USART: SR/DR/BRR/CR1..3/GTPR) ---------------------------------------- */

typedef struct {
    volatile uint32_t SR, DR, BRR, CR1, CR2, CR3, GTPR;
} usart_regs;
#define USART1 ((usart_regs *)0x40011000u)
#define USART2 ((usart_regs *)0x40004400u)
#define USART3 ((usart_regs *)0x40004800u)
#define UART4 ((usart_regs *)0x40004C00u)
#define UART5 ((usart_regs *)0x40005000u)
#define USART6 ((usart_regs *)0x40011400u)
#define USART_SR_ORE (1u << 3)
#define USART_SR_RXNE (1u << 5)
#define USART_SR_TC (1u << 6)
#define USART_SR_TXE (1u << 7)
#define USART_CR1_RE (1u << 2)
#define USART_CR1_TE (1u << 3)
#define USART_CR1_RXNEIE (1u << 5)
#define USART_CR1_TXEIE (1u << 7)
#define USART_CR1_UE (1u << 13)
#define USART_CR3_DMAT (1u << 7)

/* ---- DMA (one stream's registers; the controller's status registers) --------------------- */

typedef struct {
    volatile uint32_t CR, NDTR, PAR, M0AR, M1AR, FCR;
} dma_stream_regs;
typedef struct {
    volatile uint32_t LISR, HISR, LIFCR, HIFCR;
    dma_stream_regs S[8];
} dma_regs;
#define DMA1 ((dma_regs *)0x40026000u)
#define DMA_CR_EN (1u << 0)
#define DMA_CR_TCIE (1u << 4)
#define DMA_CR_DIR_M2P (1u << 6)
#define DMA_CR_MINC (1u << 10)
#define DMA_CR_CHSEL(n) ((uint32_t)(n) << 25)
#define DMA_HIFCR_S6_ALL (0x3Du << 16) /* TCIF6, HTIF6, TEIF6, DMEIF6, FEIF6 */

/* ---- Timers (the general/advanced layout; unused fields are reserved on basic timers) ---- */

typedef struct {
    volatile uint32_t CR1, CR2, SMCR, DIER, SR, EGR, CCMR1, CCMR2, CCER, CNT, PSC, ARR, RCR,
        CCR1, CCR2, CCR3, CCR4, BDTR, DCR, DMAR, OR;
} tim_regs;
#define TIM1 ((tim_regs *)0x40010000u)
#define TIM2 ((tim_regs *)0x40000000u)
#define TIM3 ((tim_regs *)0x40000400u)
#define TIM4 ((tim_regs *)0x40000800u)
#define TIM5 ((tim_regs *)0x40000C00u)
#define TIM_CR1_CEN (1u << 0)
#define TIM_CR1_UDIS (1u << 1)
#define TIM_CR1_URS (1u << 2)
#define TIM_CR1_OPM (1u << 3)
#define TIM_CR1_ARPE (1u << 7)
#define TIM_CR1_DIR (1u << 4)
#define TIM_CR2_MMS_UPDATE (2u << 4)
#define TIM_CR2_MMS_OC1REF (4u << 4)
#define TIM_SMCR_SMS_ENCODER3 3u
#define TIM_SMCR_SMS_TRIGGER 6u
#define TIM_SMCR_SMS_EXTCLK1 7u
#define TIM_SMCR_TS_ITR0 (0u << 4)
#define TIM_DIER_UIE (1u << 0)
#define TIM_DIER_CC1IE (1u << 1)
#define TIM_SR_UIF (1u << 0)
#define TIM_SR_CC1IF (1u << 1)
#define TIM_EGR_UG (1u << 0)
#define TIM_CCMR_OC1M_FORCE_LOW (4u << 4)
#define TIM_CCMR_OC1M_PWM2 (7u << 4)
#define TIM_CCMR_OC1PE (1u << 3)
#define TIM_CCMR_OC2M_PWM1 (6u << 12)
#define TIM_CCMR_OC2PE (1u << 11)
#define TIM_CCMR_CC1S_TI1 (1u << 0)
#define TIM_CCMR_CC2S_TI2 (1u << 8)
#define TIM_CCMR_IC1F(f) ((uint32_t)(f) << 4)
#define TIM_CCMR_IC2F(f) ((uint32_t)(f) << 12)
#define TIM_CCER_CC1E (1u << 0)
#define TIM_CCER_CC2E (1u << 4)
#define TIM_BDTR_MOE (1u << 15)
#define TIM_CCMR_OC1M_MASK (7u << 4)

/* ---- SPI -------------------------------------------------------------------------------- */

typedef struct {
    volatile uint32_t CR1, CR2, SR, DR, CRCPR, RXCRCR, TXCRCR, I2SCFGR, I2SPR;
} spi_regs;
#define SPI2 ((spi_regs *)0x40003800u)
#define SPI_CR1_CPHA (1u << 0)
#define SPI_CR1_MSTR (1u << 2)
#define SPI_CR1_BR_DIV4 (1u << 3)
#define SPI_CR1_SPE (1u << 6)
#define SPI_CR1_SSI (1u << 8)
#define SPI_CR1_SSM (1u << 9)
#define SPI_SR_RXNE (1u << 0)
#define SPI_SR_TXE (1u << 1)
#define SPI_SR_BSY (1u << 7)

/* ---- IWDG ------------------------------------------------------------------------------- */

typedef struct {
    volatile uint32_t KR, PR, RLR, SR;
} iwdg_regs;
#define IWDG ((iwdg_regs *)0x40003000u)
#define IWDG_KEY_UNLOCK 0x5555u
#define IWDG_KEY_RELOAD 0xAAAAu
#define IWDG_KEY_START 0xCCCCu

/* ---- RNG -------------------------------------------------------------------------------- */

typedef struct {
    volatile uint32_t CR, SR, DR;
} rng_regs;
#define RNG ((rng_regs *)0x50060800u)
#define RNG_CR_RNGEN (1u << 2)
#define RNG_SR_DRDY (1u << 0)
#define RNG_SR_CECS (1u << 1)
#define RNG_SR_SECS (1u << 2)

/* ---- Interrupt masking ------------------------------------------------------------------ */

static inline void irq_disable(void) { __asm volatile("cpsid i" ::: "memory"); }
static inline void irq_enable(void) { __asm volatile("cpsie i" ::: "memory"); }
static inline void wait_for_interrupt(void) { __asm volatile("wfi" ::: "memory"); }

#endif
