# The firmware core's sources and flags, for every build that links the core (this
# directory's tests, firmware/board/, firmware/sim/). Include it with
#   include firmware/core/core.mk       (or a path relative to the including Makefile)
# CORE_DIR is this file's directory, whatever the including Makefile's directory.
CORE_DIR := $(patsubst %/,%,$(dir $(lastword $(MAKEFILE_LIST))))
# The core's files (rig_core_internal.h says what each one does).
CORE_SRC := $(CORE_DIR)/rig_core.c $(CORE_DIR)/rig_tx.c $(CORE_DIR)/rig_state.c \
            $(CORE_DIR)/rig_commands.c $(CORE_DIR)/rig_rx.c $(CORE_DIR)/rig_tick.c \
            $(CORE_DIR)/rig_frame.c $(CORE_DIR)/rig_wire.c
CORE_HDR := $(CORE_DIR)/rig_core.h $(CORE_DIR)/rig_core_internal.h \
            $(CORE_DIR)/rig_frame.h $(CORE_DIR)/rig_wire.h \
            $(CORE_DIR)/rig_hal.h $(CORE_DIR)/step_burst.h
CORE_CFLAGS := -std=c11 -Wall -Wextra -Werror -Wconversion -Wshadow -I$(CORE_DIR)
