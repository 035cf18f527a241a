/*
 * A native fhobs FMU as one translation unit: the step kernel of the numpy runtime
 * (kernel.c), the generated design data and step plans of this FMU (model_data.c), its model
 * (models.c) and the FMI 2.0 co-simulation functions (fmi2_layer.c). The plant FMU adds
 * noise.c (its measurement noise), compiled separately.
 */
#include "fhobs_native.h"
#include "kernel.c"
#include "model_data.c"
#include "models.c"
#include "fmi2_layer.c"
