/* FMI 3.0 co-simulation API of the native hydrolink FMU: each call mapped onto hydro_core.
 * Errors reach the importer as fmi3Error with a logged message; nothing here aborts. The
 * functions of other interface types (model exchange, scheduled execution, clocks, other variable
 * types) exist, as FMI 3 requires, and answer fmi3Error with a message. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "hydro_core.h"

typedef struct {
    hl_fmu *core;
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback logger;
    char *name;
    int logging;
} inst_t;

static void fmi3_log(void *env, int level, const char *message) {
    inst_t *c = env;
    if (!c->logger || (level == HL_INFO && !c->logging)) return;   /* errors and warnings always */
    c->logger(c->env, level == HL_ERROR ? fmi3Error : level == HL_WARNING ? fmi3Warning : fmi3OK,
              level == HL_ERROR ? "logStatusError" : level == HL_WARNING ? "logStatusWarning" : "logEvents", message);
}

static fmi3Status unsupported(fmi3Instance c, const char *what) {
    if (c) hl_log(((inst_t *)c)->core, 1, "%s is not supported by this co-simulation FMU", what);
    return fmi3Error;
}

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance c, fmi3Boolean on, size_t n, const fmi3String categories[]) {
    (void)n; (void)categories;
    ((inst_t *)c)->logging = on;
    return fmi3OK;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String name, fmi3String token, fmi3String resources, fmi3Boolean visible,
                                         fmi3Boolean loggingOn, fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference required[], size_t nRequired,
                                         fmi3InstanceEnvironment env, fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)token; (void)visible; (void)eventModeUsed; (void)earlyReturnAllowed; (void)required; (void)nRequired;
    (void)intermediateUpdate;
    inst_t *c = calloc(1, sizeof *c);
    if (!c) return NULL;
    c->env = env;
    c->logger = logMessage;
    c->logging = loggingOn;
    c->name = malloc(strlen(name ? name : "hydrolink") + 1);
    if (!c->name) { free(c); return NULL; }
    strcpy(c->name, name ? name : "hydrolink");
    char path[4096];
    snprintf(path, sizeof path, "%s", resources ? resources : "");
    size_t k = strlen(path);
    if (k > 1 && path[k - 1] == '/') path[k - 1] = 0;   /* FMI 3: a path with a trailing separator */
    c->core = hl_new(path, c->name, fmi3_log, c);
    if (!c->core) { free(c->name); free(c); return NULL; }
    return c;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String name, fmi3String token, fmi3String resources, fmi3Boolean visible,
                                          fmi3Boolean loggingOn, fmi3InstanceEnvironment env, fmi3LogMessageCallback log) {
    (void)name; (void)token; (void)resources; (void)visible; (void)loggingOn;
    if (log) log(env, fmi3Error, "logStatusError", "this FMU is for co-simulation only");
    return NULL;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String name, fmi3String token, fmi3String resources, fmi3Boolean visible,
                                               fmi3Boolean loggingOn, fmi3InstanceEnvironment env, fmi3LogMessageCallback log,
                                               fmi3ClockUpdateCallback clockUpdate, fmi3LockPreemptionCallback lock,
                                               fmi3UnlockPreemptionCallback unlock) {
    (void)name; (void)token; (void)resources; (void)visible; (void)loggingOn; (void)clockUpdate; (void)lock; (void)unlock;
    if (log) log(env, fmi3Error, "logStatusError", "this FMU is for co-simulation only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance c) {
    inst_t *i = c;
    if (!i) return;
    hl_terminate(i->core);
    hl_free(i->core);
    free(i->name);
    free(i);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance c, fmi3Boolean tolDefined, fmi3Float64 tol, fmi3Float64 start,
                                       fmi3Boolean stopDefined, fmi3Float64 stop) {
    (void)tolDefined; (void)tol; (void)stopDefined; (void)stop;
    if (start != 0.0) { hl_log(((inst_t *)c)->core, 1, "the start time must be 0 (got %g)", start); return fmi3Error; }
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance c) { return hl_start(((inst_t *)c)->core) ? fmi3Error : fmi3OK; }
fmi3Status fmi3EnterEventMode(fmi3Instance c) { return unsupported(c, "event mode"); }
fmi3Status fmi3Terminate(fmi3Instance c) { hl_terminate(((inst_t *)c)->core); return fmi3OK; }
fmi3Status fmi3Reset(fmi3Instance c) { hl_terminate(((inst_t *)c)->core); return fmi3OK; }

fmi3Status fmi3GetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t n, fmi3Float64 v[], size_t nv) {
    if (nv != n) return unsupported(c, "arrays");
    return hl_get_reals(((inst_t *)c)->core, vr, n, v) ? fmi3Error : fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t n, const fmi3Float64 v[], size_t nv) {
    if (nv != n) return unsupported(c, "arrays");
    return hl_set_reals(((inst_t *)c)->core, vr, n, v) ? fmi3Error : fmi3OK;
}

fmi3Status fmi3GetString(fmi3Instance c, const fmi3ValueReference vr[], size_t n, fmi3String v[], size_t nv) {
    if (nv != n) return unsupported(c, "arrays");
    return hl_get_strings(((inst_t *)c)->core, vr, n, v) ? fmi3Error : fmi3OK;
}

fmi3Status fmi3SetString(fmi3Instance c, const fmi3ValueReference vr[], size_t n, const fmi3String v[], size_t nv) {
    if (nv != n) return unsupported(c, "arrays");
    return hl_set_strings(((inst_t *)c)->core, vr, n, v) ? fmi3Error : fmi3OK;
}

/* variable types this FMU has none of */
#define NONE_OF(T, NAME)                                                                                         \
    fmi3Status fmi3Get##NAME(fmi3Instance c, const fmi3ValueReference vr[], size_t n, T v[], size_t nv) {       \
        (void)vr; (void)v; (void)nv; return n ? unsupported(c, #NAME " variables") : fmi3OK;                    \
    }                                                                                                            \
    fmi3Status fmi3Set##NAME(fmi3Instance c, const fmi3ValueReference vr[], size_t n, const T v[], size_t nv) { \
        (void)vr; (void)v; (void)nv; return n ? unsupported(c, #NAME " variables") : fmi3OK;                    \
    }
NONE_OF(fmi3Float32, Float32)
NONE_OF(fmi3Int8, Int8)
NONE_OF(fmi3UInt8, UInt8)
NONE_OF(fmi3Int16, Int16)
NONE_OF(fmi3UInt16, UInt16)
NONE_OF(fmi3Int32, Int32)
NONE_OF(fmi3UInt32, UInt32)
NONE_OF(fmi3Int64, Int64)
NONE_OF(fmi3UInt64, UInt64)
NONE_OF(fmi3Boolean, Boolean)

fmi3Status fmi3GetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t n, size_t sizes[], fmi3Binary v[], size_t nv) {
    (void)vr; (void)sizes; (void)v; (void)nv; return n ? unsupported(c, "Binary variables") : fmi3OK;
}
fmi3Status fmi3SetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t n, const size_t sizes[],
                         const fmi3Binary v[], size_t nv) {
    (void)vr; (void)sizes; (void)v; (void)nv; return n ? unsupported(c, "Binary variables") : fmi3OK;
}
fmi3Status fmi3GetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t n, fmi3Clock v[]) {
    (void)vr; (void)v; return n ? unsupported(c, "clocks") : fmi3OK;
}
fmi3Status fmi3SetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t n, const fmi3Clock v[]) {
    (void)vr; (void)v; return n ? unsupported(c, "clocks") : fmi3OK;
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance c, fmi3ValueReference vr, size_t *n) {
    (void)vr; (void)n; return unsupported(c, "fmi3GetNumberOfVariableDependencies (see the model description)");
}
fmi3Status fmi3GetVariableDependencies(fmi3Instance c, fmi3ValueReference d, size_t ed[], fmi3ValueReference ind[],
                                       size_t ei[], fmi3DependencyKind kinds[], size_t n) {
    (void)d; (void)ed; (void)ind; (void)ei; (void)kinds; (void)n;
    return unsupported(c, "fmi3GetVariableDependencies (see the model description)");
}

fmi3Status fmi3GetFMUState(fmi3Instance c, fmi3FMUState *state) {
    void *s = NULL;
    if (hl_get_state(((inst_t *)c)->core, &s)) return fmi3Error;
    *state = s;
    return fmi3OK;
}
fmi3Status fmi3SetFMUState(fmi3Instance c, fmi3FMUState state) {
    return hl_set_state(((inst_t *)c)->core, state) ? fmi3Error : fmi3OK;
}
fmi3Status fmi3FreeFMUState(fmi3Instance c, fmi3FMUState *state) {
    if (state && *state) { hl_free_state(((inst_t *)c)->core, *state); *state = NULL; }
    return fmi3OK;
}
fmi3Status fmi3SerializedFMUStateSize(fmi3Instance c, fmi3FMUState s, size_t *n) {
    (void)s; (void)n; return unsupported(c, "serializing an FMU state");
}
fmi3Status fmi3SerializeFMUState(fmi3Instance c, fmi3FMUState s, fmi3Byte b[], size_t n) {
    (void)s; (void)b; (void)n; return unsupported(c, "serializing an FMU state");
}
fmi3Status fmi3DeserializeFMUState(fmi3Instance c, const fmi3Byte b[], size_t n, fmi3FMUState *s) {
    (void)s; (void)b; (void)n; return unsupported(c, "deserializing an FMU state");
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance c, const fmi3ValueReference u[], size_t nu, const fmi3ValueReference k[],
                                        size_t nk, const fmi3Float64 seed[], size_t ns, fmi3Float64 sens[], size_t nsens) {
    (void)u; (void)nu; (void)k; (void)nk; (void)seed; (void)ns; (void)sens; (void)nsens;
    return unsupported(c, "directional derivatives");
}
fmi3Status fmi3GetAdjointDerivative(fmi3Instance c, const fmi3ValueReference u[], size_t nu, const fmi3ValueReference k[],
                                    size_t nk, const fmi3Float64 seed[], size_t ns, fmi3Float64 sens[], size_t nsens) {
    (void)u; (void)nu; (void)k; (void)nk; (void)seed; (void)ns; (void)sens; (void)nsens;
    return unsupported(c, "adjoint derivatives");
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance c) { return unsupported(c, "configuration mode"); }
fmi3Status fmi3ExitConfigurationMode(fmi3Instance c) { return unsupported(c, "configuration mode"); }

fmi3Status fmi3GetIntervalDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t n, fmi3Float64 iv[],
                                  fmi3IntervalQualifier q[]) {
    (void)vr; (void)n; (void)iv; (void)q; return unsupported(c, "clocks");
}
fmi3Status fmi3GetIntervalFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t n, fmi3UInt64 cnt[],
                                   fmi3UInt64 res[], fmi3IntervalQualifier q[]) {
    (void)vr; (void)n; (void)cnt; (void)res; (void)q; return unsupported(c, "clocks");
}
fmi3Status fmi3GetShiftDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t n, fmi3Float64 s[]) {
    (void)vr; (void)n; (void)s; return unsupported(c, "clocks");
}
fmi3Status fmi3GetShiftFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t n, fmi3UInt64 cnt[], fmi3UInt64 res[]) {
    (void)vr; (void)n; (void)cnt; (void)res; return unsupported(c, "clocks");
}
fmi3Status fmi3SetIntervalDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t n, const fmi3Float64 iv[]) {
    (void)vr; (void)n; (void)iv; return unsupported(c, "clocks");
}
fmi3Status fmi3SetIntervalFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t n, const fmi3UInt64 cnt[],
                                   const fmi3UInt64 res[]) {
    (void)vr; (void)n; (void)cnt; (void)res; return unsupported(c, "clocks");
}
fmi3Status fmi3SetShiftDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t n, const fmi3Float64 s[]) {
    (void)vr; (void)n; (void)s; return unsupported(c, "clocks");
}
fmi3Status fmi3SetShiftFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t n, const fmi3UInt64 cnt[],
                                const fmi3UInt64 res[]) {
    (void)vr; (void)n; (void)cnt; (void)res; return unsupported(c, "clocks");
}
fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance c) { return unsupported(c, "event mode"); }
fmi3Status fmi3UpdateDiscreteStates(fmi3Instance c, fmi3Boolean *a, fmi3Boolean *b, fmi3Boolean *d, fmi3Boolean *e,
                                    fmi3Boolean *f, fmi3Float64 *g) {
    (void)a; (void)b; (void)d; (void)e; (void)f; (void)g; return unsupported(c, "event mode");
}
fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance c) { return unsupported(c, "model exchange"); }
fmi3Status fmi3CompletedIntegratorStep(fmi3Instance c, fmi3Boolean no, fmi3Boolean *e, fmi3Boolean *t) {
    (void)no; (void)e; (void)t; return unsupported(c, "model exchange");
}
fmi3Status fmi3SetTime(fmi3Instance c, fmi3Float64 t) { (void)t; return unsupported(c, "model exchange"); }
fmi3Status fmi3SetContinuousStates(fmi3Instance c, const fmi3Float64 x[], size_t n) {
    (void)x; (void)n; return unsupported(c, "model exchange");
}
fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance c, fmi3Float64 d[], size_t n) {
    (void)d; (void)n; return unsupported(c, "model exchange");
}
fmi3Status fmi3GetEventIndicators(fmi3Instance c, fmi3Float64 e[], size_t n) {
    (void)e; (void)n; return unsupported(c, "model exchange");
}
fmi3Status fmi3GetContinuousStates(fmi3Instance c, fmi3Float64 x[], size_t n) {
    (void)x; (void)n; return unsupported(c, "model exchange");
}
fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance c, fmi3Float64 x[], size_t n) {
    (void)x; (void)n; return unsupported(c, "model exchange");
}
fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance c, size_t *n) { *n = 0; (void)c; return fmi3OK; }
fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance c, size_t *n) { *n = 0; (void)c; return fmi3OK; }
fmi3Status fmi3EnterStepMode(fmi3Instance c) { (void)c; return fmi3OK; }
fmi3Status fmi3GetOutputDerivatives(fmi3Instance c, const fmi3ValueReference vr[], size_t n, const fmi3Int32 o[],
                                    fmi3Float64 v[], size_t nv) {
    (void)vr; (void)n; (void)o; (void)v; (void)nv; return unsupported(c, "output derivatives");
}

fmi3Status fmi3DoStep(fmi3Instance c, fmi3Float64 t, fmi3Float64 h, fmi3Boolean noSetPrior, fmi3Boolean *eventNeeded,
                      fmi3Boolean *terminate, fmi3Boolean *earlyReturn, fmi3Float64 *lastTime) {
    (void)noSetPrior;
    *eventNeeded = fmi3False;
    *terminate = fmi3False;
    *earlyReturn = fmi3False;
    if (hl_do_step(((inst_t *)c)->core, t, h)) { *lastTime = t; return fmi3Error; }
    *lastTime = t + h;
    return fmi3OK;
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance c, fmi3ValueReference clock, fmi3Float64 t) {
    (void)clock; (void)t; return unsupported(c, "scheduled execution");
}
