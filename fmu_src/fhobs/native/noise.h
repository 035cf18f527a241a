/* Measurement noise of the native plant FMU (noise.c). */
#ifndef FHOBS_NOISE_H
#define FHOBS_NOISE_H

#include <stddef.h>
#include <stdint.h>

/* Hidden in a native FMU's library (which exports its fmi2 functions only); exported when
 * FHOBS_EXPORT is defined (noise.c compiled alone for ctypes). As kernel.h's. */
#ifndef FHOBS_HIDDEN
#if !defined(FHOBS_EXPORT) && (defined(__GNUC__) || defined(__clang__)) &&                     \
    !defined(_WIN32) && !defined(__CYGWIN__)
#define FHOBS_HIDDEN __attribute__((visibility("hidden")))
#else
#define FHOBS_HIDDEN
#endif
#endif

/* numpy.random.default_rng([seed, block]).uniform(-1.0, 1.0, size=count), bit for bit. */
FHOBS_HIDDEN void fhobs_noise_block(uint32_t seed, uint32_t block, size_t count, double *out);

#endif
