/* FMI 2.0 co-simulation API of the native hydrolink FMU: each call mapped onto hydro_core.
 * Errors reach the importer as fmi2Error with a logged message; nothing here aborts. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "hydro_core.h"

typedef struct {
    hl_fmu *core;
    fmi2CallbackFunctions cb;
    char *name;
    int logging;
    int initialized;
} inst_t;

/* the message as the logger's format, its '%' doubled: masters that format it (C) and masters that
 * take it as text (fmpy's ctypes callback cannot read variadic arguments) both show it */
static void fmi2_log(void *env, int level, const char *message) {
    inst_t *c = env;
    char text[4096];
    size_t k = 0;
    for (const char *p = message; *p && k + 2 < sizeof text; p++) {
        if (*p == '%') text[k++] = '%';
        text[k++] = *p;
    }
    text[k] = 0;
    if (!c->cb.logger || (level == HL_INFO && !c->logging)) return;   /* errors and warnings always */
    c->cb.logger(c->cb.componentEnvironment, c->name,
                 level == HL_ERROR ? fmi2Error : level == HL_WARNING ? fmi2Warning : fmi2OK,
                 level == HL_ERROR ? "logStatusError" : level == HL_WARNING ? "logStatusWarning" : "logEvents", text);
}

/* "file:///a/b/resources" or a plain path -> a path */
static void uri_to_path(const char *uri, char *out, size_t n) {
    const char *p = uri ? uri : "";
    if (!strncmp(p, "file://", 7)) {
        p += 7;
        if (!strncmp(p, "localhost/", 10)) p += 9;
    } else if (!strncmp(p, "file:", 5)) {
        p += 5;
    }
    size_t k = 0;
    for (; *p && k + 1 < n; p++) {   /* %XX escapes */
        if (p[0] == '%' && p[1] && p[2]) {
            char hex[3] = {p[1], p[2], 0};
            out[k++] = (char)strtol(hex, NULL, 16);
            p += 2;
        } else {
            out[k++] = *p;
        }
    }
    out[k] = 0;
    if (k > 1 && out[k - 1] == '/') out[k - 1] = 0;
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String categories[]) {
    (void)n; (void)categories;
    ((inst_t *)c)->logging = on;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible, fmi2Boolean loggingOn) {
    (void)guid; (void)visible;
    inst_t *c = calloc(1, sizeof *c);
    if (!c) return NULL;
    if (functions) c->cb = *functions;
    c->logging = loggingOn;
    c->name = malloc(strlen(name ? name : "hydrolink") + 1);
    if (!c->name) { free(c); return NULL; }
    strcpy(c->name, name ? name : "hydrolink");
    if (type != fmi2CoSimulation) {
        fmi2_log(c, 1, "this FMU is for co-simulation only");
        free(c->name); free(c);
        return NULL;
    }
    char path[4096];
    uri_to_path(resources, path, sizeof path);
    c->core = hl_new(path, c->name, fmi2_log, c);
    if (!c->core) { free(c->name); free(c); return NULL; }
    return c;
}

void fmi2FreeInstance(fmi2Component c) {
    inst_t *i = c;
    if (!i) return;
    hl_terminate(i->core);
    hl_free(i->core);
    free(i->name);
    free(i);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDefined, fmi2Real tol, fmi2Real start,
                               fmi2Boolean stopDefined, fmi2Real stop) {
    (void)tolDefined; (void)tol; (void)stopDefined; (void)stop;
    if (start != 0.0) { hl_log(((inst_t *)c)->core, 1, "the start time must be 0 (got %g)", start); return fmi2Error; }
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    inst_t *i = c;
    if (hl_start(i->core)) return fmi2Error;
    i->initialized = 1;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) { hl_terminate(((inst_t *)c)->core); return fmi2OK; }

fmi2Status fmi2Reset(fmi2Component c) {
    inst_t *i = c;
    hl_terminate(i->core);
    i->initialized = 0;
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    return hl_get_reals(((inst_t *)c)->core, vr, n, value) ? fmi2Error : fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    return hl_set_reals(((inst_t *)c)->core, vr, n, value) ? fmi2Error : fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String value[]) {
    return hl_get_strings(((inst_t *)c)->core, vr, n, value) ? fmi2Error : fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String value[]) {
    return hl_set_strings(((inst_t *)c)->core, vr, n, value) ? fmi2Error : fmi2OK;
}

static fmi2Status no_such(fmi2Component c, const char *what, size_t n) {
    if (!n) return fmi2OK;
    hl_log(((inst_t *)c)->core, 1, "this FMU has no %s variables", what);
    return fmi2Error;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    (void)vr; (void)v; return no_such(c, "integer", n);
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) {
    (void)vr; (void)v; return no_such(c, "integer", n);
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) {
    (void)vr; (void)v; return no_such(c, "boolean", n);
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) {
    (void)vr; (void)v; return no_such(c, "boolean", n);
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    void *s = NULL;
    if (hl_get_state(((inst_t *)c)->core, &s)) return fmi2Error;
    *state = s;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    return hl_set_state(((inst_t *)c)->core, state) ? fmi2Error : fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    if (state && *state) { hl_free_state(((inst_t *)c)->core, *state); *state = NULL; }
    return fmi2OK;
}

static fmi2Status unsupported(fmi2Component c, const char *what) {
    hl_log(((inst_t *)c)->core, 1, "%s is not supported by this FMU (see its model description)", what);
    return fmi2Error;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) {
    (void)s; (void)n; return unsupported(c, "serializing an FMU state");
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) {
    (void)s; (void)b; (void)n; return unsupported(c, "serializing an FMU state");
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s) {
    (void)s; (void)b; (void)n; return unsupported(c, "deserializing an FMU state");
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real dv[], fmi2Real dz[]) {
    (void)u; (void)nu; (void)z; (void)nz; (void)dv; (void)dz; return unsupported(c, "fmi2GetDirectionalDerivative");
}
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr; (void)n; (void)order; (void)value; return unsupported(c, "input derivatives");
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr; (void)n; (void)order; (void)value; return unsupported(c, "output derivatives");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    (void)noSetPrior;
    return hl_do_step(((inst_t *)c)->core, t, h) ? fmi2Error : fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) { return unsupported(c, "fmi2CancelStep (doStep never runs asynchronously)"); }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *v) {
    (void)s; (void)v; return unsupported(c, "fmi2GetStatus");
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v) {
    (void)s; (void)v; return unsupported(c, "fmi2GetRealStatus");
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v) {
    (void)s; (void)v; return unsupported(c, "fmi2GetIntegerStatus");
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v) {
    (void)s; (void)v; return unsupported(c, "fmi2GetBooleanStatus");
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v) {
    (void)s; (void)v; return unsupported(c, "fmi2GetStringStatus");
}
