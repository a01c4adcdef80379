/* The NUCLEO board's non-volatile memory (cal_flash.h): the load-cell calibration as a log
 * of records in two flash sectors, and the boot counter in a third.
 *
 * Calibration. Sectors 5 and 6 (0x08020000 and 0x08040000, 128 KiB each) hold 32-byte
 * slots; a record is 5 words: seq, load_offset, gain (f32 bits), CRC-32 of those three,
 * then the magic "CAL2", programmed last: a slot is a record only once its magic and CRC
 * are there, so a power cut at any word leaves an invalid slot and the previous record.
 * The calibration in force is the valid record with the highest seq in either sector.
 * A store programs the first blank slot after the last used one in the active sector (the
 * newest record's); when that sector is full it goes on in the other one, which the boot
 * erased. Erasing takes up to 2 s (RM0390 / the datasheet's t_ERASE128KB), so it happens
 * only in cal_flash_boot(), before the watchdog and the tick start: a store programs 5
 * words (about 80 us) and never erases, and the previous record stays until the next boot
 * has found the new one.
 *
 * Boot counter. Sector 7 (0x08060000): one word per boot holding the count; erased when
 * full (32 768 boots), at boot.
 */
#include "cal_flash.h"

#include <string.h>

#include "stm32f4_regs.h"

#define CAL_MAGIC 0x3250414Cu /* "LAP2" little-endian: a record's last word */
#define SLOT_WORDS 8u
#define CAL_SECTOR0 5u /* sectors 5 and 6 */
#define BOOT_SECTOR 7u

extern uint32_t __calib_start[], __calib_size[], __boots_start[], __boots_size[];

static unsigned active;    /* the sector (0 or 1) new records go to */
static bool other_blank;   /* the other sector is erased: the log may go on there */

static volatile uint32_t *sector_words(unsigned k) {
    uint32_t words = (uint32_t)(uintptr_t)__calib_size / 8u; /* words per sector */
    return (volatile uint32_t *)(uintptr_t)__calib_start + k * words;
}

static uint32_t slots_per_sector(void) {
    return (uint32_t)(uintptr_t)__calib_size / 2u / (SLOT_WORDS * 4u);
}

/* CRC-32 (IEEE 802.3, reflected, bitwise) of n words, little-endian bytes. */
static uint32_t crc32_words(const uint32_t *w, unsigned n) {
    uint32_t crc = 0xFFFFFFFFu;
    for (unsigned i = 0; i < n; i++) {
        for (unsigned b = 0; b < 4u; b++) {
            crc ^= (w[i] >> (8u * b)) & 0xFFu;
            for (int k = 0; k < 8; k++) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
        }
    }
    return ~crc;
}

static bool slot_blank(const volatile uint32_t *s) {
    for (unsigned i = 0; i < SLOT_WORDS; i++)
        if (s[i] != 0xFFFFFFFFu) return false;
    return true;
}

static bool slot_record(const volatile uint32_t *s, rig_calibration *out) {
    uint32_t w[3] = {s[0], s[1], s[2]};
    if (s[4] != CAL_MAGIC || s[3] != crc32_words(w, 3)) return false;
    float gain;
    memcpy(&gain, &w[2], sizeof gain);
    if (!(gain > 0.0f && gain < 1.0f) || w[0] == 0u) return false;
    out->seq = w[0];
    out->load_offset = (int32_t)w[1];
    out->load_gain_n = gain;
    return true;
}

/* The log fills a sector from slot 0 without holes (a slot a power cut left blank is
 * reused), so its used slots are those before the first blank one. */
static uint32_t first_blank(unsigned k) {
    const volatile uint32_t *w = sector_words(k);
    uint32_t i = 0, n = slots_per_sector();
    while (i < n && !slot_blank(w + i * SLOT_WORDS)) i++;
    return i;
}

/* The newest record of sector k (seq 0 when it holds none). */
static rig_calibration newest_in(unsigned k) {
    rig_calibration best = {0, 0.0f, 0u}, r;
    const volatile uint32_t *w = sector_words(k);
    for (uint32_t i = 0, used = first_blank(k); i < used; i++)
        if (slot_record(w + i * SLOT_WORDS, &r) && r.seq > best.seq) best = r;
    return best;
}

static bool flash_wait(void) {
    /* a word programs in 16 us, a 128 KiB sector erases in up to 2 s (168 MHz: ~10^9
     * loops); the loop is bounded all the same */
    for (uint32_t tries = 0; tries < 0x40000000u && (FLASH->SR & FLASH_SR_BSY); tries++) {
    }
    bool ok = (FLASH->SR & FLASH_SR_ERRORS) == 0u;
    FLASH->SR = FLASH_SR_ERRORS;
    return ok;
}

static void flash_unlock(void) {
    FLASH->KEYR = FLASH_KEY1;
    FLASH->KEYR = FLASH_KEY2;
    FLASH->SR = FLASH_SR_ERRORS;
}

static bool flash_program(volatile uint32_t *addr, uint32_t value) {
    FLASH->CR = FLASH_CR_PSIZE_X32 | FLASH_CR_PG;
    *addr = value;
    bool ok = flash_wait();
    FLASH->CR = 0;
    return ok && *addr == value;
}

static void flash_erase(uint32_t sector) {
    FLASH->CR = FLASH_CR_PSIZE_X32 | FLASH_CR_SER | FLASH_CR_SNB(sector);
    FLASH->CR |= FLASH_CR_STRT;
    (void)flash_wait();
    FLASH->CR = 0;
}

uint32_t cal_flash_count_boot(void) {
    volatile uint32_t *log = (volatile uint32_t *)(uintptr_t)__boots_start;
    uint32_t words = (uint32_t)(uintptr_t)__boots_size / 4u, slot = 0, count = 0;
    while (slot < words && log[slot] != 0xFFFFFFFFu) count = log[slot++];
    count++;
    flash_unlock();
    if (slot == words) {
        flash_erase(BOOT_SECTOR);
        slot = 0;
    }
    (void)flash_program(&log[slot], count);
    FLASH->CR = FLASH_CR_LOCK;
    return count;
}

rig_calibration cal_flash_boot(rig_calibration defaults) {
    rig_calibration a = newest_in(0), b = newest_in(1);
    active = b.seq > a.seq ? 1u : 0u;
    rig_calibration newest = active ? b : a;
    unsigned other = 1u - active;
    other_blank = first_blank(other) == 0;
    if (!other_blank) { /* its records are all older than the active sector's newest */
        flash_unlock();
        flash_erase(CAL_SECTOR0 + other);
        FLASH->CR = FLASH_CR_LOCK;
        other_blank = first_blank(other) == 0;
    }
    return newest.seq ? newest : defaults;
}

bool hal_nvm_store(const rig_calibration *cal) {
    volatile uint32_t *w = sector_words(active);
    uint32_t next = first_blank(active);
    if (next == slots_per_sector()) { /* full: on in the sector the boot erased */
        if (!other_blank) return false;
        active = 1u - active;
        other_blank = false;
        w = sector_words(active);
        next = 0;
    }
    volatile uint32_t *slot = w + next * SLOT_WORDS;
    uint32_t words[3] = {cal->seq, (uint32_t)cal->load_offset, 0u};
    memcpy(&words[2], &cal->load_gain_n, sizeof words[2]);
    uint32_t record[5] = {words[0], words[1], words[2], crc32_words(words, 3), CAL_MAGIC};
    flash_unlock();
    bool ok = true;
    for (unsigned i = 0; i < 5u && ok; i++) ok = flash_program(&slot[i], record[i]);
    FLASH->CR = FLASH_CR_LOCK;
    rig_calibration back;
    return ok && slot_record(slot, &back) && back.seq == cal->seq &&
           back.load_offset == cal->load_offset;
}
