/* The native hydrolink FMU's core: the FMU's variables, its session with a hydrolink server
 * (protocol/SPEC.md over ZMTP 3.0, written here: no libzmq, no Python) and its saved states.
 * fmi2.c and fmi3.c map their FMI version's API onto these functions; nothing here knows FMI.
 *
 * Value references (the same in both model descriptions, written by clients/fmu/native.py):
 *   0 time (FMI 3's independent variable), 1 server_address (string parameter), 2 timeout (s, parameter), 3 wave_elevation (output);
 *   1000 + 8 i + k for active DOF i: k = 0 displacement, 1 velocity (inputs), 2 force,
 *     3 excitation, 4 radiation, 5 hydrostatic, 6 dynamic (= force - hydrostatic) (outputs),
 *     7 net buoyancy (constant output; heave DOFs);
 *   1000000 + i na + j: the added mass of DOFs i, j for the importer's mass matrix (A_inf, or
 *     A(omega0) with radiation = "constant") and 2000000 + i na + j: the hydrostatic stiffness
 *     (constant outputs: masters connect outputs, not calculated parameters).
 * Every function returns 0 on success and -1 on an error it has logged. The server's setup warnings
 * (SPEC §5.1: its HDB readers' among them) are logged at HL_WARNING when the session opens. */
#ifndef HYDRO_CORE_H
#define HYDRO_CORE_H

#include <stddef.h>

#define HL_VR_TIME 0u
#define HL_VR_SERVER 1u
#define HL_VR_TIMEOUT 2u
#define HL_VR_ETA 3u
#define HL_VR_DOF 1000u
#define HL_VR_AINF 1000000u
#define HL_VR_KHS 2000000u

/* log levels: what the importer's logger gets (FMI status OK / Error / Warning) */
#define HL_INFO 0
#define HL_ERROR 1
#define HL_WARNING 2
typedef void (*hl_log_fn)(void *env, int level, const char *message);
typedef struct hl_fmu hl_fmu;

hl_fmu *hl_new(const char *resources, const char *name, hl_log_fn log, void *env);
void hl_free(hl_fmu *f);
int hl_set_reals(hl_fmu *f, const unsigned vr[], size_t n, const double value[]);
int hl_get_reals(hl_fmu *f, const unsigned vr[], size_t n, double value[]);
int hl_set_strings(hl_fmu *f, const unsigned vr[], size_t n, const char *const value[]);
int hl_get_strings(hl_fmu *f, const unsigned vr[], size_t n, const char *value[]);
int hl_start(hl_fmu *f);                 /* connect, hello (HDB files by hash, uploads on a miss), log setup.warnings */
int hl_do_step(hl_fmu *f, double time, double step);
int hl_get_state(hl_fmu *f, void **state);
int hl_set_state(hl_fmu *f, const void *state);
void hl_free_state(hl_fmu *f, void *state);
void hl_terminate(hl_fmu *f);            /* bye and close; the instance may be started again */
void hl_log(hl_fmu *f, int level, const char *fmt, ...);

#endif
