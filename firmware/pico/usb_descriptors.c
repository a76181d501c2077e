/* USB descriptors: a CDC ACM device "contactid DAQ-1" with the board's unique id as serial number. */
#include "pico/unique_id.h"
#include "tusb.h"

#define USB_VID 0x2E8A   /* Raspberry Pi */
#define USB_PID 0x000A   /* the Pico SDK's CDC device id; a product sold as such needs an id of its own */

static const tusb_desc_device_t DEVICE = {
    .bLength = sizeof(tusb_desc_device_t), .bDescriptorType = TUSB_DESC_DEVICE, .bcdUSB = 0x0200,
    .bDeviceClass = TUSB_CLASS_MISC, .bDeviceSubClass = MISC_SUBCLASS_COMMON, .bDeviceProtocol = MISC_PROTOCOL_IAD,
    .bMaxPacketSize0 = CFG_TUD_ENDPOINT0_SIZE, .idVendor = USB_VID, .idProduct = USB_PID, .bcdDevice = 0x0100,
    .iManufacturer = 1, .iProduct = 2, .iSerialNumber = 3, .bNumConfigurations = 1,
};

enum { ITF_CDC = 0, ITF_CDC_DATA, ITF_TOTAL };
#define EP_NOTIFY 0x81
#define EP_OUT 0x02
#define EP_IN 0x82
#define CONFIG_LENGTH (TUD_CONFIG_DESC_LEN + TUD_CDC_DESC_LEN)

static const uint8_t CONFIGURATION[] = {
    TUD_CONFIG_DESCRIPTOR(1, ITF_TOTAL, 0, CONFIG_LENGTH, 0x00, 100),
    TUD_CDC_DESCRIPTOR(ITF_CDC, 4, EP_NOTIFY, 8, EP_OUT, EP_IN, 64),
};

const uint8_t *tud_descriptor_device_cb(void) { return (const uint8_t *)&DEVICE; }

const uint8_t *tud_descriptor_configuration_cb(uint8_t index)
{
    (void)index;
    return CONFIGURATION;
}

/* String descriptors: UTF-16, first element = type and byte length. */
const uint16_t *tud_descriptor_string_cb(uint8_t index, uint16_t langid)
{
    static uint16_t text[40];
    char serial[2 * PICO_UNIQUE_BOARD_ID_SIZE_BYTES + 1];
    const char *ascii;
    (void)langid;
    switch (index) {
    case 0: text[1] = 0x0409; text[0] = (uint16_t)((TUSB_DESC_STRING << 8) | 4); return text;
    case 1: ascii = "contactid"; break;
    case 2: ascii = "contactid DAQ-1"; break;
    case 3: pico_get_unique_board_id_string(serial, sizeof serial); ascii = serial; break;
    case 4: ascii = "DAQ-1"; break;
    default: return NULL;
    }
    uint8_t n = 0;
    while (ascii[n] && n < 39) {
        text[1 + n] = (uint8_t)ascii[n];
        n++;
    }
    text[0] = (uint16_t)((TUSB_DESC_STRING << 8) | (2 * n + 2));
    return text;
}
