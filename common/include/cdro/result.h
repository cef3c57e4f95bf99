/*
 * result.h: the one error model of common/. Functions return cdro_result_t: 0 is success,
 * CDRO_PENDING (> 0) means "more bytes are needed", and each negative value is a distinct
 * reason for rejecting input, counted separately by receivers.
 */
#ifndef CDRO_RESULT_H
#define CDRO_RESULT_H

#ifdef __cplusplus
extern "C" {
#endif

typedef enum cdro_result {
    CDRO_PENDING = 1, /* no complete frame yet: feed more bytes */
    CDRO_OK = 0,
    CDRO_ERR_ARGUMENT = -1, /* caller error: a buffer too small, a NULL pointer */
    CDRO_ERR_COBS = -2,     /* the bytes between two delimiters are not valid COBS */
    CDRO_ERR_SHORT = -3,    /* fewer bytes than a header and a CRC */
    CDRO_ERR_CRC = -4,      /* CRC mismatch: corrupted in transit */
    CDRO_ERR_VERSION = -5,  /* valid CRC, other protocol version: a mismatched build */
    CDRO_ERR_TYPE = -6,     /* valid CRC, unknown frame type */
    CDRO_ERR_LENGTH = -7,   /* length field disagrees with the bytes or the type's layout */
    CDRO_ERR_TOO_LONG = -8, /* no delimiter within the longest possible frame */
    CDRO_ERR_VALUE = -9     /* well-formed, but a field is outside its documented range */
} cdro_result_t;

/* Short stable name of a status ("ok", "crc", ...), for logs and counters. */
const char *cdro_result_name(int status);

#ifdef __cplusplus
}
#endif

#endif /* CDRO_RESULT_H */
