/* The NUCLEO board's flash: the load-cell calibration log (sectors 5 and 6, two sectors
 * alternating, records with a sequence number and a CRC) and the boot counter (sector 7).
 * It implements hal_nvm_store() of rig_hal.h. docs/firmware.md, "Flash". */
#ifndef CAL_FLASH_H
#define CAL_FLASH_H

#include <stdbool.h>
#include <stdint.h>

#include "rig_hal.h"

/* Count this boot in sector 7; returns the count (1 at the first boot). Erases the sector
 * when its log is full: call before the watchdog starts. */
uint32_t cal_flash_count_boot(void);

/* Find the newest valid calibration record (defaults when none) and erase the sector not
 * holding it, if it is not blank, so that stores never erase: call at boot, before the
 * watchdog starts. */
rig_calibration cal_flash_boot(rig_calibration defaults);

#endif
