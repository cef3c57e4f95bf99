#include "cdro/checkpoint_layout.h"

#include "layout_codec.h"

CDRO_CHECKPOINT_RECORD_LIST(CDRO_X_ENCODER)
CDRO_CHECKPOINT_RECORD_LIST(CDRO_X_DECODER)

size_t cdro_service_info_encode(const cdro_service_info_t *info, uint8_t *out)
{
    cdro_service_info_t block = *info;
    block.version = (uint8_t)CDRO_CHECKPOINT_SERVICE_INFO_VERSION;
    return encode_service_info(&block, out);
}

cdro_result_t cdro_service_info_decode(const uint8_t *in, size_t len, cdro_service_info_t *out)
{
    if (len < (size_t)CDRO_SERVICE_INFO_MAX_SIZE) {
        return CDRO_ERR_LENGTH;
    }
    /* Cannot fail: the block's bytes are there. */
    (void)decode_service_info(in, CDRO_SERVICE_INFO_MAX_SIZE, out);
    return out->version == CDRO_CHECKPOINT_SERVICE_INFO_VERSION ? CDRO_OK : CDRO_ERR_VERSION;
}
