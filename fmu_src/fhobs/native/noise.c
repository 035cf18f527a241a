/*
 * Measurement noise of the native plant FMU: the same numbers as the numpy runtime
 * (fhobs.core.plant.uniform_noise), which draws block b of a seed from
 * numpy.random.default_rng([seed, b]).uniform(-1.0, 1.0, size).
 *
 * default_rng([seed, b]) is numpy's PCG64 (XSL-RR output, 128-bit LCG) seeded by a
 * SeedSequence of the entropy words (seed, b); uniform(-1, 1) is -1 + 2 d with the double
 * d = (next64 >> 11) 2^-53. Everything below follows numpy's published algorithms
 * (numpy/random/bit_generator.pyx, numpy/random/src/pcg64); a test compares this file's
 * draws with numpy's, bit for bit.
 */
#include <stddef.h>
#include <stdint.h>

#include "noise.h"

/* SeedSequence constants (bit_generator.pyx) */
#define POOL_SIZE 4
#define INIT_A 0x43b0d7e5u
#define MULT_A 0x931e8875u
#define INIT_B 0x8b51f9ddu
#define MULT_B 0x58f38dedu
#define MIX_MULT_L 0xca01f9ddu
#define MIX_MULT_R 0x4973f715u
#define XSHIFT 16

/* Unsigned 128-bit integers as two 64-bit halves (ISO C has no 128-bit type). */
typedef struct {
    uint64_t hi, lo;
} u128;

static u128 u128_make(uint64_t hi, uint64_t lo)
{
    u128 r;
    r.hi = hi;
    r.lo = lo;
    return r;
}

static u128 u128_add(u128 a, u128 b)
{
    u128 r;
    r.lo = a.lo + b.lo;
    r.hi = a.hi + b.hi + (r.lo < a.lo);
    return r;
}

/* a b modulo 2^128 */
static u128 u128_mul(u128 a, u128 b)
{
    const uint64_t mask = 0xffffffffu;
    uint64_t a0 = a.lo & mask, a1 = a.lo >> 32, b0 = b.lo & mask, b1 = b.lo >> 32;
    uint64_t p00 = a0 * b0, p01 = a0 * b1, p10 = a1 * b0, p11 = a1 * b1;
    uint64_t middle = (p00 >> 32) + (p01 & mask) + (p10 & mask);
    u128 r;
    r.lo = (middle << 32) | (p00 & mask);
    r.hi = p11 + (p01 >> 32) + (p10 >> 32) + (middle >> 32) + a.hi * b.lo + a.lo * b.hi;
    return r;
}

static uint32_t hashmix(uint32_t value, uint32_t *hash_const)
{
    value ^= *hash_const;
    *hash_const *= MULT_A;
    value *= *hash_const;
    value ^= value >> XSHIFT;
    return value;
}

static uint32_t mix(uint32_t x, uint32_t y)
{
    uint32_t result = MIX_MULT_L * x - MIX_MULT_R * y;
    result ^= result >> XSHIFT;
    return result;
}

/* SeedSequence(entropy).pool for two entropy words (fewer than the pool size). */
static void seed_pool(const uint32_t entropy[2], uint32_t pool[POOL_SIZE])
{
    uint32_t hash_const = INIT_A;
    for (int i = 0; i < POOL_SIZE; i++)
        pool[i] = hashmix(i < 2 ? entropy[i] : 0u, &hash_const);
    for (int src = 0; src < POOL_SIZE; src++)
        for (int dst = 0; dst < POOL_SIZE; dst++)
            if (src != dst)
                pool[dst] = mix(pool[dst], hashmix(pool[src], &hash_const));
}

/* SeedSequence.generate_state(4, uint64): eight 32-bit words, read as little-endian pairs. */
static void generate_state(const uint32_t pool[POOL_SIZE], uint64_t out[4])
{
    uint32_t hash_const = INIT_B, words[8];
    for (int i = 0; i < 8; i++) {
        uint32_t value = pool[i % POOL_SIZE];
        value ^= hash_const;
        hash_const *= MULT_B;
        value *= hash_const;
        value ^= value >> XSHIFT;
        words[i] = value;
    }
    for (int i = 0; i < 4; i++)
        out[i] = (uint64_t)words[2 * i] | ((uint64_t)words[2 * i + 1] << 32);
}

typedef struct {
    u128 state, inc;
} Pcg64;

static const u128 PCG_MULTIPLIER = {2549297995355413924ULL, 4865540595714422341ULL};

static void pcg_step(Pcg64 *rng)
{
    rng->state = u128_add(u128_mul(rng->state, PCG_MULTIPLIER), rng->inc);
}

/* pcg64_set_seed: state and increment from the four generated words (high word first). */
static void pcg_seed(Pcg64 *rng, const uint64_t words[4])
{
    u128 initstate = u128_make(words[0], words[1]);
    rng->state = u128_make(0, 0);
    rng->inc = u128_make(words[2] << 1 | words[3] >> 63, words[3] << 1 | 1u); /* initseq << 1 | 1 */
    pcg_step(rng);
    rng->state = u128_add(rng->state, initstate);
    pcg_step(rng);
}

static uint64_t pcg_next64(Pcg64 *rng)
{
    pcg_step(rng);
    uint64_t x = rng->state.hi ^ rng->state.lo;
    unsigned rot = (unsigned)(rng->state.hi >> 58);
    return (x >> rot) | (x << ((64u - rot) & 63u));
}

void fhobs_noise_block(uint32_t seed, uint32_t block, size_t count, double *out)
{
    const uint32_t entropy[2] = {seed, block};
    uint32_t pool[POOL_SIZE];
    uint64_t words[4];
    Pcg64 rng;
    seed_pool(entropy, pool);
    generate_state(pool, words);
    pcg_seed(&rng, words);
    for (size_t i = 0; i < count; i++)
        out[i] = -1.0 + 2.0 * ((double)(pcg_next64(&rng) >> 11) * (1.0 / 9007199254740992.0));
}
