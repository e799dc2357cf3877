/* A heaving body with a linear PTO damper as an FMI 2.0 co-simulation FMU (hydrolink's tests).
 *
 *   (m + a_inf + a_in) z'' = F + F0 - c_pto z' - (k_hs + k_in) z
 *
 * F: the input force, constant over a step; a_in, k_in, F0: inputs for an added mass, a stiffness
 * and a constant force another FMU publishes as outputs (a master connects outputs to inputs, not
 * to parameters), added to the parameters a_inf and k_hs.
 *
 * Outputs: heave displacement z, velocity v, PTO power P_pto = c_pto v^2 and the absorbed energy
 * E_pto (integral of P_pto). Each doStep integrates with `substeps` classical Runge-Kutta steps.
 * The FMU state (for rollback) is the whole instance struct, copied by value. */

#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"

#define GUID "{hydrolink-heave-body-0001}"

enum { VR_M, VR_A_INF, VR_K_HS, VR_C_PTO, VR_Z0, VR_V0, VR_F, VR_Z, VR_V, VR_P, VR_E, VR_A_IN, VR_K_IN, VR_F0,
       N_REAL };
enum { VR_SUBSTEPS = 0 };

typedef struct {
    double r[N_REAL];
    int substeps;
    double time;
    int initialised;
} Body;

typedef struct {
    Body body;
    fmi2CallbackFunctions cb;
    char name[64];
} Instance;

static void derivatives(const Body *b, const double y[3], double dy[3]) {
    const double *r = b->r;
    double v = y[1];
    dy[0] = v;
    dy[1] = (r[VR_F] + r[VR_F0] - r[VR_C_PTO] * v - (r[VR_K_HS] + r[VR_K_IN]) * y[0])
            / (r[VR_M] + r[VR_A_INF] + r[VR_A_IN]);
    dy[2] = r[VR_C_PTO] * v * v;
}

static void rk4(const Body *b, double y[3], double h) {
    double k1[3], k2[3], k3[3], k4[3], t[3];
    int i;
    derivatives(b, y, k1);
    for (i = 0; i < 3; i++) t[i] = y[i] + 0.5 * h * k1[i];
    derivatives(b, t, k2);
    for (i = 0; i < 3; i++) t[i] = y[i] + 0.5 * h * k2[i];
    derivatives(b, t, k3);
    for (i = 0; i < 3; i++) t[i] = y[i] + h * k3[i];
    derivatives(b, t, k4);
    for (i = 0; i < 3; i++) y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
}

static void outputs(Body *b) {
    b->r[VR_P] = b->r[VR_C_PTO] * b->r[VR_V] * b->r[VR_V];
}

/* ---------------------------------------------------------------- common functions */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]) {
    (void)c; (void)on; (void)n; (void)cat;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources,
                              const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean logging) {
    Instance *inst;
    (void)resources; (void)visible; (void)logging;
    if (type != fmi2CoSimulation || guid == NULL || strcmp(guid, GUID) != 0) return NULL;
    inst = (Instance *)calloc(1, sizeof(Instance));
    if (inst == NULL) return NULL;
    if (cb != NULL) inst->cb = *cb;
    strncpy(inst->name, name ? name : "heave_body", sizeof(inst->name) - 1);
    inst->body.r[VR_M] = 261.8e3;
    inst->body.substeps = 10;
    return inst;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDef, fmi2Real tol, fmi2Real start,
                               fmi2Boolean stopDef, fmi2Real stop) {
    (void)tolDef; (void)tol; (void)stopDef; (void)stop;
    ((Instance *)c)->body.time = start;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Body *b = &((Instance *)c)->body;
    if (!(b->r[VR_M] + b->r[VR_A_INF] > 0.0) || b->substeps < 1) return fmi2Error;
    b->r[VR_Z] = b->r[VR_Z0];
    b->r[VR_V] = b->r[VR_V0];
    b->r[VR_E] = 0.0;
    outputs(b);
    b->initialised = 1;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { (void)c; return fmi2Error; }

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Body *b = &((Instance *)c)->body;
    size_t i;
    for (i = 0; i < n; i++) {
        if (vr[i] >= N_REAL) return fmi2Error;
        value[i] = b->r[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Body *b = &((Instance *)c)->body;
    size_t i;
    for (i = 0; i < n; i++) {
        if (vr[i] >= N_REAL || (vr[i] > VR_F && vr[i] < VR_A_IN)) return fmi2Error;   /* outputs cannot be set */
        if (b->initialised && vr[i] < VR_F) return fmi2Error;                         /* fixed parameters */
        b->r[vr[i]] = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer value[]) {
    size_t i;
    for (i = 0; i < n; i++) {
        if (vr[i] != VR_SUBSTEPS) return fmi2Error;
        value[i] = ((Instance *)c)->body.substeps;
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer value[]) {
    Body *b = &((Instance *)c)->body;
    size_t i;
    for (i = 0; i < n; i++) {
        if (vr[i] != VR_SUBSTEPS || b->initialised) return fmi2Error;
        b->substeps = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) {
    (void)c; (void)vr; (void)v;
    return n == 0 ? fmi2OK : fmi2Error;
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    (void)c; (void)vr; (void)v;
    return n == 0 ? fmi2OK : fmi2Error;
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) {
    (void)c; (void)vr; (void)v;
    return n == 0 ? fmi2OK : fmi2Error;
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) {
    (void)c; (void)vr; (void)v;
    return n == 0 ? fmi2OK : fmi2Error;
}

/* ---------------------------------------------------------------- state (rollback) */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    Body *copy = (Body *)(*state != NULL ? *state : malloc(sizeof(Body)));
    if (copy == NULL) return fmi2Error;
    *copy = ((Instance *)c)->body;
    *state = copy;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    if (state == NULL) return fmi2Error;
    ((Instance *)c)->body = *(const Body *)state;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    (void)c;
    if (state != NULL) {
        free(*state);
        *state = NULL;
    }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *size) {
    (void)c; (void)s; (void)size;
    return fmi2Error;
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte bytes[], size_t size) {
    (void)c; (void)s; (void)bytes; (void)size;
    return fmi2Error;
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate *s) {
    (void)c; (void)bytes; (void)size; (void)s;
    return fmi2Error;
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference k[], size_t nk, const fmi2Real dk[],
                                        fmi2Real du[]) {
    (void)c; (void)u; (void)nu; (void)k; (void)nk; (void)dk; (void)du;
    return fmi2Error;
}

/* ---------------------------------------------------------------- co-simulation */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)c; (void)vr; (void)n; (void)order; (void)value;
    return fmi2Error;
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)c; (void)vr; (void)n; (void)order; (void)value;
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noRollback) {
    Body *b = &((Instance *)c)->body;
    double y[3];
    int i;
    (void)noRollback;
    if (!b->initialised || h <= 0.0) return fmi2Error;
    y[0] = b->r[VR_Z];
    y[1] = b->r[VR_V];
    y[2] = b->r[VR_E];
    for (i = 0; i < b->substeps; i++) rk4(b, y, h / b->substeps);
    b->r[VR_Z] = y[0];
    b->r[VR_V] = y[1];
    b->r[VR_E] = y[2];
    b->time = t + h;
    outputs(b);
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) { (void)c; return fmi2Error; }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *v) {
    (void)c; (void)s; (void)v;
    return fmi2Discard;
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v) {
    if (s != fmi2LastSuccessfulTime) return fmi2Discard;
    *v = ((Instance *)c)->body.time;
    return fmi2OK;
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v) {
    (void)c; (void)s; (void)v;
    return fmi2Discard;
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v) {
    (void)c; (void)s; (void)v;
    return fmi2Discard;
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v) {
    (void)c; (void)s; (void)v;
    return fmi2Discard;
}
