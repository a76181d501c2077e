/* DAQ-1 on a Raspberry Pi Pico: USB CDC bytes in, the core, bytes out (docs/firmware.md). */
#include "daq1.h"
#include "pico/stdlib.h"
#include "tusb.h"

void daq1_board_init(void);   /* board.c */

static daq1 instrument;   /* about 170 KiB: FIFO, frame and message buffers */

int main(void)
{
    uint8_t input[64];
    uint32_t have = 0, used = 0;
    daq1_board_init();
    tusb_init();
    daq1_init(&instrument, hal_board_info());
    for (;;) {
        tud_task();
        if (used == have && daq1_accepts_input(&instrument) && tud_cdc_available()) {
            have = tud_cdc_read(input, sizeof input);
            used = 0;
        }
        if (used < have)
            used += (uint32_t)daq1_receive(&instrument, input + used, have - used);
        daq1_poll(&instrument);
    }
}
