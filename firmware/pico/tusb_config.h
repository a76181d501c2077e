/* TinyUSB: one CDC ACM interface (the DAQ-1 link). */
#ifndef TUSB_CONFIG_H
#define TUSB_CONFIG_H
#define CFG_TUSB_RHPORT0_MODE OPT_MODE_DEVICE
#define CFG_TUD_ENABLED 1
#define CFG_TUD_ENDPOINT0_SIZE 64
#define CFG_TUD_CDC 1
#define CFG_TUD_CDC_RX_BUFSIZE 512
#define CFG_TUD_CDC_TX_BUFSIZE 4096   /* the core's own FIFO holds the backlog */
#define CFG_TUD_CDC_EP_BUFSIZE 64
#endif
