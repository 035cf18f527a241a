/* Measurement noise of the native plant FMU (noise.c). */
#ifndef FHOBS_NOISE_H
#define FHOBS_NOISE_H

#include <stddef.h>
#include <stdint.h>

/* numpy.random.default_rng([seed, block]).uniform(-1.0, 1.0, size=count), bit for bit. */
void fhobs_noise_block(uint32_t seed, uint32_t block, size_t count, double *out);

#endif
