/* Result strings and the logging front end shared by every library. */
#include "hlod/hlod.h"

#include "sleeps.h"

#include <stdarg.h>
#include <stdio.h>

const char *hlod_result_str(hlod_result r)
{
    static const char *const names[HLOD_RESULT_COUNT] = {
        [HLOD_OK] = "ok",
        [HLOD_ERR_INVALID_ARG] = "invalid argument",
        [HLOD_ERR_NOMEM] = "out of memory",
        [HLOD_ERR_IO] = "input/output error",
        [HLOD_ERR_FORMAT] = "malformed file",
        [HLOD_ERR_UNSUPPORTED] = "unsupported format or feature",
        [HLOD_ERR_NAN] = "non-finite number",
        [HLOD_ERR_INDEX_RANGE] = "index out of range",
        [HLOD_ERR_EMPTY] = "empty mesh",
        [HLOD_ERR_CHECKSUM] = "checksum mismatch",
        [HLOD_ERR_VERSION] = "incompatible version",
        [HLOD_ERR_CANCELLED] = "cancelled",
    };
    if ((unsigned)r >= HLOD_RESULT_COUNT || !names[r])
        return "unknown error";
    return names[r];
}

void hlod_logf(const hlod_logger *lg, hlod_log_level level, const char *fmt, ...)
{
    if (!lg || !lg->func)
        return;
    char buf[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    long x = hlod_excuse_begin(); /* the user's logger may block (sleeps.h) */
    lg->func(lg->user_data, level, buf);
    hlod_excuse_end(x);
}

