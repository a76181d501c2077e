/* CRC-32/ISO-HDLC (zlib, Ethernet): reflected 0xEDB88320, init and final xor 0xFFFFFFFF. */
#ifndef CRC32_H
#define CRC32_H
#include <stddef.h>
#include <stdint.h>
/* Continue a CRC: start with crc = 0; crc32_update(crc32_update(0, a), b) == CRC of a followed by b. */
uint32_t crc32_update(uint32_t crc, const uint8_t *data, size_t n);
#endif
