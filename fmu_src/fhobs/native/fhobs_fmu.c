/*
 * A native fhobs FMU as one translation unit: the step kernel of the numpy runtime
 * (kernel.c), the planner that computes the plan of each communication step size at its
 * first use (planner.c; the homogeneous observers' gain levels: gain_levels.c), the generated
 * design data of this FMU (model_data.c), its model (models.c) and the FMI 2.0 co-simulation
 * functions (fmi2_layer.c). The plant FMU adds noise.c (its measurement noise), compiled
 * separately.
 */
#include "fhobs_native.h"
#include "kernel.c"
#include "planner.c"
#include "model_data.c"
#if FHOBS_KIND == FHOBS_KIND_OBSERVER || FHOBS_KIND == FHOBS_KIND_PRESCRIBED_TIME
#include "gain_levels.c"
#endif
#include "models.c"
#include "fmi2_layer.c"
