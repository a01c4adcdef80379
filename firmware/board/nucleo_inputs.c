/* What hal_read reports on the NUCLEO-F446RE (board_nucleo.h): the encoder (TIM2 in encoder
 * mode), the load cell (ADS131M02 on SPI2, its presence, DRDY, CRC and STATUS checked), the
 * switches, and the board's own faults (INTERNAL, OVERTRAVEL, LOAD_ADC, CLOCK, STOP_CHAIN). */
#include "board_nucleo.h"

#define ADC_DRDY_TICKS 3u     /* ticks without a conversion (one every 256 us) */
#define STOP_CHAIN_TICKS 20u  /* feedback may lag the enable this long (relays) */

static uint32_t adc_fault; /* ADC_* */
static uint32_t drdy_missed, chain_mismatch;
static int32_t adc_last;

/* ---- encoder: TIM2 -------------------------------------------------------------------------- */

void encoder_init(void) {
    TIM2->ARR = 0xFFFFFFFFu;
    /* TI1, TI2 filtered over 8 samples of 90 MHz (89 ns): far above the encoder's edges */
    TIM2->CCMR1 = TIM_CCMR_CC1S_TI1 | TIM_CCMR_IC1F(3) | TIM_CCMR_CC2S_TI2 | TIM_CCMR_IC2F(3);
    TIM2->CCER = 0; /* both inputs non-inverted */
    TIM2->SMCR = TIM_SMCR_SMS_ENCODER3;
    TIM2->CNT = 0;
    TIM2->CR1 = TIM_CR1_CEN;
}

/* ---- load cell: ADS131M02 on SPI2 -------------------------------------------------------- */

#define ADC_WORD 3u                 /* 24-bit words (the ADS131M02's default) */
#define ADC_FRAME (4u * ADC_WORD)   /* STATUS/response, CH0, CH1, CRC */
#define ADC_CMD_NULL 0x0000u
#define ADC_CMD_RREG(addr) (0xA000u | ((uint32_t)(addr) << 7)) /* one register */
#define ADC_CMD_WREG(addr) (0x6000u | ((uint32_t)(addr) << 7)) /* one register */
#define ADC_REG_ID 0x00u
#define ADC_REG_MODE 0x02u
#define ADC_REG_GAIN 0x04u
#define ADC_ID_M02 0x22u            /* ID[15:8]: 0x2 and CHANCNT = 2 */
#define ADC_MODE_24BIT 0x0110u      /* WLENGTH 24 bits, SPI timeout on, RESET flag cleared */
#define ADC_GAIN_CH0_128 0x0007u
#define ADC_STATUS_FAULTS 0x7400u   /* F_RESYNC, REG_MAP, CRC_ERR, RESET */
#define ADC_STATUS_WLENGTH 0x0300u
#define ADC_STATUS_WLENGTH_24 0x0100u
#define SPI_WAIT_TRIES 1000u        /* a byte takes 0.7 us: about 128 CPU cycles */

static bool spi_wait(uint32_t flag, bool set) {
    for (uint32_t tries = 0; tries < SPI_WAIT_TRIES; tries++)
        if (((SPI2->SR & flag) != 0u) == set) return true;
    return false;
}

/* One frame; false when SPI2 did not finish a byte (the chip select is released). */
static bool spi_frame(const uint8_t *out, uint8_t *in) {
    bool ok = true;
    pin_write(GPIOB, PIN_CS, false);
    for (unsigned i = 0; i < ADC_FRAME && ok; i++) {
        ok = spi_wait(SPI_SR_TXE, true);
        if (ok) SPI2->DR = out[i];
        ok = ok && spi_wait(SPI_SR_RXNE, true);
        in[i] = ok ? (uint8_t)SPI2->DR : 0u;
    }
    ok = spi_wait(SPI_SR_BSY, false) && ok;
    pin_write(GPIOB, PIN_CS, true);
    return ok;
}

/* CRC-16-CCITT (0x1021, initial 0xFFFF), the ADS131M02's output CRC over the words before it */
static uint16_t adc_crc(const uint8_t *data, unsigned n) {
    uint16_t crc = 0xFFFFu;
    for (unsigned i = 0; i < n; i++) {
        crc = (uint16_t)(crc ^ ((uint16_t)data[i] << 8));
        for (int b = 0; b < 8; b++)
            crc = (uint16_t)((crc & 0x8000u) ? ((uint32_t)crc << 1) ^ 0x1021u : (uint32_t)crc << 1);
    }
    return crc;
}

static uint16_t word16(const uint8_t *w) { return (uint16_t)((w[0] << 8) | w[1]); }

/* A frame with a command (and one data word); its CRC checked. 0 or an ADC_* code. */
static uint32_t adc_command(uint32_t cmd, uint32_t data, uint8_t in[ADC_FRAME]) {
    uint8_t out[ADC_FRAME] = {0};
    out[0] = (uint8_t)(cmd >> 8);
    out[1] = (uint8_t)cmd;
    out[ADC_WORD] = (uint8_t)(data >> 8);
    out[ADC_WORD + 1u] = (uint8_t)data;
    if (!spi_frame(out, in)) return ADC_SPI_TIMEOUT;
    if (adc_crc(in, 3u * ADC_WORD) != word16(&in[3u * ADC_WORD])) return ADC_BAD_CRC;
    return 0;
}

/* Configure the converter and check that it is there: the ID register's answer (in the
 * frame after the RREG) names an ADS131M02 and every frame's CRC holds. */
void adc_init(void) {
    /* mode 1 (CPOL 0, CPHA 1), 45 MHz / 4 = 11.25 MHz (the ADC takes up to 25 MHz) */
    SPI2->CR1 = SPI_CR1_MSTR | SPI_CR1_BR_DIV4 | SPI_CR1_CPHA | SPI_CR1_SSM | SPI_CR1_SSI;
    SPI2->CR1 |= SPI_CR1_SPE;
    uint8_t in[ADC_FRAME];
    /* the first frame after power-on answers the reset; its CRC is checked like any */
    uint32_t err = adc_command(ADC_CMD_WREG(ADC_REG_MODE), ADC_MODE_24BIT, in);
    if (!err) err = adc_command(ADC_CMD_WREG(ADC_REG_GAIN), ADC_GAIN_CH0_128, in);
    if (!err) err = adc_command(ADC_CMD_RREG(ADC_REG_ID), 0u, in);
    if (!err) err = adc_command(ADC_CMD_NULL, 0u, in);
    if (err || in[0] != ADC_ID_M02) adc_fault = ADC_MISSING;
    /* CLOCK keeps its default: both channels, OSR 1024, high resolution */
}

/* The latest conversion when DRDY says there is one; the health checks set adc_fault. */
static int32_t adc_read(void) {
    /* no CLKIN (CLOCK_NO_HSE) means no conversions: CLOCK names the cause, not LOAD_ADC */
    if (adc_fault == ADC_MISSING || clock_fault == CLOCK_NO_HSE) return adc_last;
    if (pin_read(GPIOB, PIN_DRDY)) { /* high: nothing new since the last read */
        if (++drdy_missed >= ADC_DRDY_TICKS && !adc_fault) adc_fault = ADC_DRDY_TIMEOUT;
        return adc_last;
    }
    drdy_missed = 0;
    uint8_t in[ADC_FRAME];
    uint32_t err = adc_command(ADC_CMD_NULL, 0u, in);
    uint16_t status = word16(in);
    if (!err && ((status & ADC_STATUS_FAULTS) ||
                 (status & ADC_STATUS_WLENGTH) != ADC_STATUS_WLENGTH_24)) {
        err = ADC_BAD_STATUS;
    }
    if (err) {
        if (!adc_fault) adc_fault = err;
        return adc_last;
    }
    uint32_t raw = ((uint32_t)in[ADC_WORD] << 16) | ((uint32_t)in[ADC_WORD + 1u] << 8) |
                   in[ADC_WORD + 2u];
    adc_last = (int32_t)(raw ^ 0x800000u) - 0x800000; /* sign-extend 24 bits */
    return adc_last;
}

/* ---- hal_read ------------------------------------------------------------------ */

/* The board's faults of this period, each with its FAULT value (the first found). */
static void board_faults(rig_inputs *in) {
    uint16_t bits = 0;
    int32_t detail = 0;
    if (step_error || late_tick) {
        bits |= RIG_F_INTERNAL;
        detail = step_error ? INTERNAL_STEP_BURST : INTERNAL_LATE_TICK;
        late_tick = false;
    }
    bool open_end = pin_read(GPIOC, PIN_LIMIT_OPEN), closed_end = pin_read(GPIOC, PIN_LIMIT_CLOSED);
    if (open_end || closed_end) {
        if (!bits) detail = (open_end ? 1 : 0) | (closed_end ? 2 : 0);
        bits |= RIG_F_OVERTRAVEL;
    }
    if (adc_fault) {
        if (!bits) detail = (int32_t)adc_fault;
        bits |= RIG_F_LOAD_ADC;
    }
    if (clock_fault) {
        if (!bits) detail = (int32_t)clock_fault;
        bits |= RIG_F_CLOCK;
    }
    /* the stop chain: its feedback follows the enable unless the stop button opened it */
    bool feedback = pin_read(GPIOB, PIN_CHAIN);
    if (feedback != driver_on && !in->stop_input) {
        if (chain_mismatch < STOP_CHAIN_TICKS) chain_mismatch++;
    } else {
        chain_mismatch = 0;
    }
    if (chain_mismatch >= STOP_CHAIN_TICKS) {
        if (!bits) detail = driver_on ? 1 : 2; /* 1: chain open, 2: enable stuck live */
        bits |= RIG_F_STOP_CHAIN;
    }
    in->board_faults = bits;
    in->board_detail = detail;
}

void hal_read(rig_inputs *in) {
    in->enc = (int32_t)TIM2->CNT;
    in->load_raw = adc_read();
    in->home_switch = !pin_read(GPIOC, PIN_HOME);
    in->stop_input = pin_read(GPIOB, PIN_STOP) || !pin_read(GPIOC, PIN_B1);
    in->driver_alarm = pin_read(GPIOB, PIN_ALARM);
    board_faults(in);
}

