/*
 * brake_car.c: one rail car braked by a pneumatic cylinder, as an FMI 2.0 co-simulation FMU.
 *
 * The model and the FMI 2.0 co-simulation functions in one file, plain C99, no framework; compiled against
 * the standard FMI 2.0 headers (fmi2Functions.h ...) that the importing tool provides (FMPy: fmpy/c-code).
 * It uses no function of the maths library (isfinite and fabs are compiler built-ins), so the shared
 * library needs nothing beyond the C library.
 *
 * The physics is railhil's plant (plant_sim) for one car, same equations, same integrator, same numbers:
 *
 *   cylinder  EP valve opening u in [-1, 1] fills at u * 1.0 MPa/s (u > 0) or vents at u * 1.5 MPa/s
 *             (u < 0); the WSP dump valve overrides it: FILL (0) lets the EP valve act, HOLD (1) isolates
 *             the cylinder, VENT (2) dumps it at 2.0 MPa/s; then 0 <= p <= p_max = 450 kPa.
 *             (plant_sim/brake.py: cylinder_pressure_scalar, valve_table; eq. (5a) seed 001)
 *   torque    the play operator between a squeeze line tau = 0.08 p - 2400 and a release line 800 N m
 *             above it, tau >= 0 (brake.py: hysteresis_torque_scalar; eqs. (6), (10a) seed 001)
 *   adhesion  seed 001's slip-speed curve mu(s) = 2 mu_peak x / (1 + x^2), x = s / s_peak, s_peak =
 *             0.155 m/s, which beyond the peak never falls below 0.2 mu_peak, a sliding wheel's friction
 *             (plant_sim/adhesion.py: mu_slip_speed_scalar; params.py: AdhesionParams(slip_speed_peak=
 *             (mu_peak, 0.155), slip_speed_slide_ratio=0.2); railhil's default ratio is 0, seed 001's bare
 *             curve, which leaves a locked wheel almost no adhesion; 0.2 is params.LOCKED_RATIO's choice),
 *             f = mu N, N = m g (eq. (1a) seed 001)
 *   car       m dv/dt = -f - (c0 + c1 v + c2 v^2) (Davis, eq. (4) seed 003; dynamics.py:
 *             other_force_scalar, davis_resistance_scalar; no couplers, no grade: one car on the level)
 *   wheel     J domega/dt = r f - tau (eq. (1b) seed 001), carried as the slip speed s = v - r omega:
 *             ds/dt = F_other/m + (r/J) tau - (1/m + r^2/J) f (eq. (3) seed 001; dynamics.py:
 *             slip_rate_scalar)
 *   step      linearly-implicit Euler for v and s (the adhesion force linearised by its chord f/s over
 *             the step: stable for the stiff slip dynamics at any step), v >= 0 (a car cannot roll back),
 *             0 <= s <= v (0 <= omega <= v/r), symplectic Euler for x (plant_sim/kernel.py:
 *             integrate_car_scalar; plant_sim/plant.py explains the scheme)
 *   sensors   the axle speed quantised to 0.005 rad/s, the cylinder pressure to 10 Pa, round half to even,
 *             no noise (plant_sim/sensors.py: sensor_readings; params.py: SensorParams)
 *
 * A communication step longer than DT_MAX_S (1 ms, PlantParams.dt_us) is split into n equal sub-steps of
 * at most 1 ms. Inputs are checked as they are set (plant_sim/kernel.py: step_cars): a non-finite valve
 * opening is taken as 0 (valve closed: pressure held), an out-of-range one is clipped to [-1, 1], a dump
 * state other than 0, 1, 2 is taken as FILL; each is reported to the logger (rate-limited) and the call
 * returns fmi2Warning. Parameters outside their range are refused (fmi2Error, a message naming them).
 */

#include <math.h>      /* isfinite, fabs: compiler built-ins, no libm */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define MODEL_GUID "{baeb2366-5ccd-4f8a-bed5-5eb2aadabd8e}"   /* the same as in modelDescription.xml */

/* ---------------------------------------------------------------------------------- value references */
enum {
    VR_U_VALVE = 0,     /* Real input: EP valve opening [1] */
    VR_DUMP = 1,        /* Integer input: WSP dump valve, 0 FILL, 1 HOLD, 2 VENT */
    VR_OMEGA_AXLE = 2,  /* Real outputs ... */
    VR_P_CYL = 3,
    VR_A_LONG = 4,
    VR_X = 5,
    VR_V = 6,
    VR_S_SLIP = 7,
    VR_P_TRUE = 8,
    VR_V0 = 9,          /* Real parameters ... */
    VR_X0 = 10,
    VR_MASS = 11,
    VR_MU_PEAK = 12
};

/* WSP dump-valve states (plant_sim/brake.py: WSP_FILL, WSP_HOLD, WSP_VENT) */
enum { DUMP_FILL = 0, DUMP_HOLD = 1, DUMP_VENT = 2 };

/* ------------------------------------------------------------------------------------ constants, SI */
/* plant_sim/params.py: BrakeParams */
#define P_MAX_PA            450e3           /* reservoir pressure p_max, eq. (5) seed 001 */
#define FILL_RATE_PA_S      1.0e6           /* EP valve capacity at full opening */
#define VENT_RATE_PA_S      1.5e6           /* EP valve exhaust at full opening */
#define WSP_VENT_RATE_PA_S  2.0e6           /* WSP dump valve */
#define ALPHA_SQUEEZE       0.08            /* squeeze line tau = alpha p + beta [N m/Pa], eq. (6) seed 001 */
#define BETA_SQUEEZE        (-0.08 * 30e3)  /* [N m]: crosses 0 at the 30 kPa return-spring preload */
#define ALPHA_RELEASE       0.08            /* release line, 20 kPa above the squeeze line */
#define BETA_RELEASE        (-0.08 * 30e3 + 0.08 * 20e3)
/* plant_sim/params.py: TrainParams (one car is the leading car: its nose's c2) */
#define WHEEL_RADIUS_M      0.46            /* r */
#define WHEEL_INERTIA_KGM2  600.0           /* J of the car's lumped wheelset */
#define G_MPS2              9.81
#define DAVIS_C0_N          800.0           /* Davis f_r = c0 + c1 v + c2 v^2, eq. (4) seed 003 */
#define DAVIS_C1_NS_M       25.0
#define DAVIS_C2_NS2_M2     8.0             /* davis_c2_lead_Ns2_per_m2 */
/* plant_sim/params.py: AdhesionParams.slip_speed_peak = (mu_peak, S_PEAK_MPS) */
#define S_PEAK_MPS          0.155           /* slip speed of the adhesion peak (issue #4's parameter set) */
#define SLIDE_RATIO         0.2             /* mu >= 0.2 mu_peak beyond the peak (params.LOCKED_RATIO) */
/* plant_sim/kernel.py */
#define S_EPS_MPS           1e-9            /* adhesion at s + S_EPS_MPS: the chord f/s stays finite */
/* plant_sim/params.py: SensorParams */
#define OMEGA_QUANTUM_RAD_S 0.005           /* axle_speed_quantum_rad_s */
#define P_QUANTUM_PA        10.0            /* pressure_quantum_Pa */
/* plant_sim/params.py: PlantParams.dt_us */
#define DT_MAX_S            1e-3            /* the longest internal step */
#define STEP_MAX_S          1e6             /* the longest communication step accepted (1e9 sub-steps) */

/* the parameters' start values (the same as in modelDescription.xml) */
#define V0_START_MPS        25.0
#define X0_START_M          0.0
#define MASS_START_KG       40000.0         /* TrainParams.masses_kg: loaded metro car */
#define MU_PEAK_START       0.2             /* seed 001 IV: f_max = 0.2 M g */

/* --------------------------------------------------------------------------------------- the model */
typedef enum { MODE_INSTANTIATED, MODE_INITIALIZATION, MODE_STEP, MODE_TERMINATED, MODE_ERROR } Mode;

/* Everything a simulation state is made of (what fmi2GetFMUstate copies). */
typedef struct {
    double v0_mps, x0_m, mass_kg, mu_peak;   /* parameters */
    double u_valve;                          /* EP valve opening as applied, in [-1, 1] */
    int dump;                                /* WSP dump valve as applied, DUMP_FILL ... DUMP_VENT */
    double x_m, v_mps, s_mps, p_pa, tau_nm;  /* state: position, speed, slip speed, pressure, torque */
    double a_mps2;                           /* dv/dt over the last sub-step (0 before the first) */
    double time_s;                           /* time at the end of the last step */
    long bad_inputs;                         /* inputs replaced by their safe value so far */
    Mode mode;
} Model;

typedef struct {
    Model m;
    char *name;
    const fmi2CallbackFunctions *cb;
    fmi2Boolean logging_on;
} Instance;

/* The state at the start: the car at x0 with v0, its wheel rolling (s = 0), the cylinder empty. */
static void reset_state(Model *m) {
    m->x_m = m->x0_m;
    m->v_mps = m->v0_mps;
    m->s_mps = 0.0;
    m->p_pa = 0.0;
    m->tau_nm = 0.0;
    m->a_mps2 = 0.0;    /* as plant_sim.plant.Plant, whose v_prev = v before the first step */
}

static void reset_model(Model *m) {
    memset(m, 0, sizeof *m);
    m->v0_mps = V0_START_MPS;
    m->x0_m = X0_START_M;
    m->mass_kg = MASS_START_KG;
    m->mu_peak = MU_PEAK_START;
    m->u_valve = 0.0;
    m->dump = DUMP_FILL;
    m->time_s = 0.0;
    m->mode = MODE_INSTANTIATED;
    reset_state(m);
}

/* mu(s) = 2 mu_peak x / (1 + x^2), x = s / s_peak, at least mu_slide beyond the peak
   (plant_sim/adhesion.py: mu_slip_speed_scalar, seed 001 II-A eq. (3)) */
static double mu_slip_speed(double s_mps, double mu_peak, double mu_slide) {
    double x = s_mps / S_PEAK_MPS;
    double mu = 2.0 * mu_peak * x / (1.0 + x * x);
    return (x > 1.0 && mu < mu_slide) ? mu_slide : mu;
}

/* One internal step of h seconds (h <= DT_MAX_S), the inputs held: plant_sim/kernel.py step_cars for one car. */
static void plant_step(Model *m, double h) {
    /* brake: cylinder pressure, exact for the valves held over the step (brake.py: cylinder_pressure_scalar) */
    double dp = 0.0;
    if (m->dump == DUMP_FILL)                  /* FILL: the EP valve fills (u > 0) or vents (u < 0) */
        dp = m->u_valve > 0.0 ? m->u_valve * (FILL_RATE_PA_S * h) : m->u_valve * (VENT_RATE_PA_S * h);
    else if (m->dump == DUMP_VENT)             /* VENT: the dump valve empties the cylinder; HOLD: nothing */
        dp = -(WSP_VENT_RATE_PA_S * h);
    double p = m->p_pa + dp;
    p = p < 0.0 ? 0.0 : p;                                        /* 0 <= p ...                      */
    m->p_pa = p > P_MAX_PA ? P_MAX_PA : p;                        /* ... <= p_max, eq. (5a) seed 001 */

    /* brake torque: the play operator (brake.py: hysteresis_torque_scalar, eq. (10a) seed 001) */
    double squeeze = ALPHA_SQUEEZE * m->p_pa + BETA_SQUEEZE;      /* squeeze line, eq. (6) seed 001 */
    double release = ALPHA_RELEASE * m->p_pa + BETA_RELEASE;      /* release line, eq. (6) seed 001 */
    double tau = squeeze > m->tau_nm ? squeeze : m->tau_nm;       /* lifted onto the squeeze line    */
    tau = release < tau ? release : tau;                          /* pushed down onto the release line */
    m->tau_nm = tau < 0.0 ? 0.0 : tau;                            /* never negative                   */

    /* forces at the start of the step */
    double v = m->v_mps, s = m->s_mps;
    double inv_m = 1.0 / m->mass_kg;
    double f_other = -DAVIS_C0_N - v * (DAVIS_C1_NS_M + DAVIS_C2_NS2_M2 * v);  /* -f_r, eq. (4) seed 003
                                                       (dynamics.py: other_force_scalar, one car, level) */
    double s_reg = s + S_EPS_MPS;                                 /* kernel.py: S_EPS_MPS             */
    double f = mu_slip_speed(s_reg, m->mu_peak, SLIDE_RATIO * m->mu_peak)
               * m->mass_kg * G_MPS2;                             /* f = mu N, eq. (1a) seed 001      */

    /* linearly-implicit Euler (kernel.py: integrate_car_scalar) */
    double gain = inv_m + WHEEL_RADIUS_M * WHEEL_RADIUS_M / WHEEL_INERTIA_KGM2;  /* 1/m + r^2/J          */
    double s_dot = f_other * inv_m + m->tau_nm * (WHEEL_RADIUS_M / WHEEL_INERTIA_KGM2)
                   - f * gain;                                    /* explicit ds/dt, eq. (3) seed 001 */
    double chord = f / s_reg;                                     /* f(s) ~ c s, c > 0                */
    double ds = s_dot / (1.0 / h + gain * chord);                 /* (1 + h (1/m + r^2/J) c) ds = h ds/dt */
    double f_new = f + chord * ds;                                /* adhesion force over the step     */
    double v_new = v + (f_other - f_new) * (inv_m * h);           /* dv/dt = (F_other - f)/m, eq. (3) seed 003 */
    v_new = v_new < 0.0 ? 0.0 : v_new;                            /* a car cannot reverse: v >= 0     */
    double s_new = s + ds;
    s_new = s_new < 0.0 ? 0.0 : s_new;
    s_new = v_new < s_new ? v_new : s_new;                        /* 0 <= s <= v: 0 <= omega <= v/r   */
    m->x_m += v_new * h;                                          /* dx/dt = v at the new v: symplectic */
    m->a_mps2 = (v_new - v) / h;                                  /* plant.py: Plant._accel           */
    m->v_mps = v_new;
    m->s_mps = s_new;
}

/* np.rint: the nearest integer, ties to even (the sensors' rounding, plant_sim/sensors.py), without libm */
static double round_half_even(double y) {
    if (!(fabs(y) < 4.0e15)) return y;          /* already an integer (or not finite) */
    double fl = (double)(long long)y;            /* toward zero ... */
    if (fl > y) fl -= 1.0;                       /* ... floor */
    double frac = y - fl;                        /* exact, in [0, 1) */
    if (frac > 0.5 || (frac == 0.5 && ((long long)fl & 1))) fl += 1.0;
    return fl;
}

/* what a sensor with this quantum reports, >= 0 (plant_sim/sensors.py: sensor_readings without noise) */
static double sensor(double truth, double quantum) {
    double q = round_half_even(truth / quantum) * quantum;
    return q < 0.0 ? 0.0 : q;
}

static int get_output(const Model *m, fmi2ValueReference vr, double *value) {
    switch (vr) {
    case VR_U_VALVE:    *value = m->u_valve; return 1;
    case VR_OMEGA_AXLE: *value = sensor((m->v_mps - m->s_mps) / WHEEL_RADIUS_M, OMEGA_QUANTUM_RAD_S);
                        return 1;                                 /* omega = (v - s)/r [rad/s]        */
    case VR_P_CYL:      *value = sensor(m->p_pa, P_QUANTUM_PA) * 1e-5; return 1;        /* [bar]      */
    case VR_A_LONG:     *value = m->a_mps2; return 1;                                   /* [m/s2]     */
    case VR_X:          *value = m->x_m; return 1;                                      /* [m]        */
    case VR_V:          *value = m->v_mps * 3.6; return 1;                              /* [km/h]     */
    case VR_S_SLIP:     *value = m->s_mps; return 1;                                    /* [m/s]      */
    case VR_P_TRUE:     *value = m->p_pa; return 1;                                     /* [Pa]       */
    case VR_V0:         *value = m->v0_mps; return 1;
    case VR_X0:         *value = m->x0_m; return 1;
    case VR_MASS:       *value = m->mass_kg; return 1;
    case VR_MU_PEAK:    *value = m->mu_peak; return 1;
    default:            return 0;
    }
}

/* ---------------------------------------------------------------------------------------- logging */
static void log_msg(const Instance *c, fmi2Status status, fmi2String category, const char *fmt, ...) {
    char buf[512];
    va_list ap;
    if (!c || !c->cb || !c->cb->logger) return;
    if (status == fmi2OK && !c->logging_on) return;   /* warnings and errors always, the rest on request */
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    c->cb->logger(c->cb->componentEnvironment, c->name, status, category, "%s", buf);
}

static fmi2Status refuse(Instance *c, const char *fmt, const char *what) {
    log_msg(c, fmi2Error, "logStatusError", fmt, what);
    return fmi2Error;
}

/* a bad input was replaced: reported the 1st, 10th, 100th ... time, so a stream of them does not flood */
static fmi2Status bad_input(Instance *c, const char *what, double got, double used) {
    long n = ++c->m.bad_inputs;
    long k = n;
    while (k % 10 == 0) k /= 10;
    if (k == 1)
        log_msg(c, fmi2Warning, "logStatusWarning", "%s = %g is not valid, %g used (bad input #%ld)",
                what, got, used, n);
    return fmi2Warning;
}

static int allowed(Instance *c, const char *fn, int modes) {
    if (!c) return 0;
    if (modes & (1 << c->m.mode)) return 1;
    log_msg(c, fmi2Error, "logStatusError", "%s: not allowed in this state (mode %d)", fn, (int)c->m.mode);
    return 0;
}
#define IN(mode) (1 << (mode))
#define ANY_MODE (IN(MODE_INSTANTIATED) | IN(MODE_INITIALIZATION) | IN(MODE_STEP) | IN(MODE_TERMINATED) \
                  | IN(MODE_ERROR))
#define RUNNING (IN(MODE_INITIALIZATION) | IN(MODE_STEP) | IN(MODE_TERMINATED) | IN(MODE_ERROR))

/* ------------------------------------------------------------------------- FMI 2.0: common functions */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    Instance *c = comp;
    (void)nCategories;
    (void)categories;   /* the two categories (logStatusWarning, logStatusError) are always on */
    if (!allowed(c, "fmi2SetDebugLogging", ANY_MODE)) return fmi2Error;
    c->logging_on = loggingOn;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    Instance probe = {0};
    (void)fmuResourceLocation;
    (void)visible;
    probe.cb = functions;
    probe.name = (char *)(instanceName ? instanceName : "brake_car");
    if (!functions || !instanceName || !instanceName[0]) return NULL;
    if (fmuType != fmi2CoSimulation) {
        log_msg(&probe, fmi2Error, "logStatusError", "fmi2Instantiate: brake_car is a co-simulation FMU only");
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, MODEL_GUID) != 0) {
        log_msg(&probe, fmi2Error, "logStatusError", "fmi2Instantiate: GUID %s does not match %s",
                fmuGUID ? fmuGUID : "(null)", MODEL_GUID);
        return NULL;
    }
    Instance *c = functions->allocateMemory ? functions->allocateMemory(1, sizeof(Instance))
                                            : calloc(1, sizeof(Instance));
    if (!c) return NULL;
    size_t n = strlen(instanceName) + 1;
    c->name = functions->allocateMemory ? functions->allocateMemory(n, 1) : calloc(n, 1);
    if (!c->name) {
        if (functions->freeMemory) functions->freeMemory(c); else free(c);
        return NULL;
    }
    memcpy(c->name, instanceName, n);
    c->cb = functions;
    c->logging_on = loggingOn;
    reset_model(&c->m);
    return c;
}

static void release(const Instance *c, void *p) {
    if (c->cb->freeMemory) c->cb->freeMemory(p); else free(p);
}

void fmi2FreeInstance(fmi2Component comp) {
    Instance *c = comp;
    if (!c) return;
    release(c, c->name);
    release(c, c);
}

fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    Instance *c = comp;
    (void)toleranceDefined;   /* fixed steps: no tolerance; the model runs past any stop time */
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (!allowed(c, "fmi2SetupExperiment", IN(MODE_INSTANTIATED))) return fmi2Error;
    if (!isfinite(startTime)) return refuse(c, "fmi2SetupExperiment: %s must be finite", "startTime");
    c->m.time_s = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component comp) {
    Instance *c = comp;
    if (!allowed(c, "fmi2EnterInitializationMode", IN(MODE_INSTANTIATED))) return fmi2Error;
    c->m.mode = MODE_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    Instance *c = comp;
    if (!allowed(c, "fmi2ExitInitializationMode", IN(MODE_INITIALIZATION))) return fmi2Error;
    reset_state(&c->m);
    c->m.mode = MODE_STEP;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component comp) {
    Instance *c = comp;
    if (!allowed(c, "fmi2Terminate", IN(MODE_STEP) | IN(MODE_ERROR))) return fmi2Error;
    c->m.mode = MODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component comp) {
    Instance *c = comp;
    if (!allowed(c, "fmi2Reset", ANY_MODE)) return fmi2Error;
    reset_model(&c->m);
    return fmi2OK;
}

/* ------------------------------------------------------------------------------ getting and setting */
fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    Instance *c = comp;
    if (!allowed(c, "fmi2GetReal", ANY_MODE)) return fmi2Error;
    for (size_t i = 0; i < nvr; i++)
        if (!get_output(&c->m, vr[i], &value[i]))
            return refuse(c, "fmi2GetReal: %s", "no Real variable has this value reference");
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    Instance *c = comp;
    if (!allowed(c, "fmi2GetInteger", ANY_MODE)) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] != VR_DUMP) return refuse(c, "fmi2GetInteger: %s", "no Integer variable has this value reference");
        value[i] = c->m.dump;
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    Instance *c = comp;
    (void)vr;
    (void)value;
    if (!allowed(c, "fmi2GetBoolean", ANY_MODE)) return fmi2Error;
    return nvr == 0 ? fmi2OK : refuse(c, "fmi2GetBoolean: %s", "the FMU has no Boolean variables");
}

fmi2Status fmi2GetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    Instance *c = comp;
    (void)vr;
    (void)value;
    if (!allowed(c, "fmi2GetString", ANY_MODE)) return fmi2Error;
    return nvr == 0 ? fmi2OK : refuse(c, "fmi2GetString: %s", "the FMU has no String variables");
}

/* a parameter's value if it is in range, else the call is refused (params.py's __post_init__ checks) */
static fmi2Status set_parameter(Instance *c, fmi2ValueReference vr, double value) {
    Model *m = &c->m;
    if (m->mode != MODE_INSTANTIATED && m->mode != MODE_INITIALIZATION)
        return refuse(c, "fmi2SetReal: %s are fixed parameters, set before initialization ends",
                      "v0, x0, mass, mu_peak");
    switch (vr) {
    case VR_V0:
        if (!(isfinite(value) && value >= 0.0 && value <= 200.0))
            return refuse(c, "fmi2SetReal: %s must be in [0, 200] m/s", "v0");
        m->v0_mps = value;
        break;
    case VR_X0:
        if (!(isfinite(value) && fabs(value) < 1e9))      /* float spacing stays << 1 mm (plant.py) */
            return refuse(c, "fmi2SetReal: %s must be within +-1e9 m", "x0");
        m->x0_m = value;
        break;
    case VR_MASS:
        if (!(isfinite(value) && value >= 1e3 && value <= 1e6))
            return refuse(c, "fmi2SetReal: %s must be in [1e3, 1e6] kg", "mass");
        m->mass_kg = value;
        break;
    default:  /* VR_MU_PEAK */
        if (!(isfinite(value) && value > 0.0 && value < 2.0))   /* AdhesionParams.slip_speed_peak */
            return refuse(c, "fmi2SetReal: %s must be in (0, 2)", "mu_peak");
        m->mu_peak = value;
        break;
    }
    reset_state(m);        /* outputs read before initialization ends show the initial state */
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    Instance *c = comp;
    fmi2Status status = fmi2OK;
    if (!allowed(c, "fmi2SetReal", IN(MODE_INSTANTIATED) | IN(MODE_INITIALIZATION) | IN(MODE_STEP)))
        return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        double u = value[i];
        switch (vr[i]) {
        case VR_U_VALVE:   /* kernel.py step_cars / brake.py sanitize_valve_cmd */
            if (!isfinite(u)) {                  /* inf or NaN: valve closed, the pressure held */
                status = bad_input(c, "u_valve", u, 0.0);
                u = 0.0;
            } else if (u < -1.0 || u > 1.0) {    /* clipped to [-1, 1] */
                double clipped = u < -1.0 ? -1.0 : 1.0;
                status = bad_input(c, "u_valve", u, clipped);
                u = clipped;
            }
            c->m.u_valve = u;
            break;
        case VR_V0: case VR_X0: case VR_MASS: case VR_MU_PEAK:
            if (set_parameter(c, vr[i], u) != fmi2OK) return fmi2Error;
            break;
        case VR_OMEGA_AXLE: case VR_P_CYL: case VR_A_LONG: case VR_X: case VR_V: case VR_S_SLIP:
        case VR_P_TRUE:
            return refuse(c, "fmi2SetReal: %s", "outputs cannot be set");
        default:
            return refuse(c, "fmi2SetReal: %s", "no Real variable has this value reference");
        }
    }
    return status;
}

fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    Instance *c = comp;
    fmi2Status status = fmi2OK;
    if (!allowed(c, "fmi2SetInteger", IN(MODE_INSTANTIATED) | IN(MODE_INITIALIZATION) | IN(MODE_STEP)))
        return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] != VR_DUMP) return refuse(c, "fmi2SetInteger: %s", "no Integer variable has this value reference");
        int w = value[i];
        if (w != DUMP_FILL && w != DUMP_HOLD && w != DUMP_VENT) {   /* brake.py sanitize_wsp_valve */
            status = bad_input(c, "dump", (double)w, (double)DUMP_FILL);
            w = DUMP_FILL;                                           /* the dump valve does nothing */
        }
        c->m.dump = w;
    }
    return status;
}

fmi2Status fmi2SetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    Instance *c = comp;
    (void)vr;
    (void)value;
    if (!allowed(c, "fmi2SetBoolean", ANY_MODE)) return fmi2Error;
    return nvr == 0 ? fmi2OK : refuse(c, "fmi2SetBoolean: %s", "the FMU has no Boolean variables");
}

fmi2Status fmi2SetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    Instance *c = comp;
    (void)vr;
    (void)value;
    if (!allowed(c, "fmi2SetString", ANY_MODE)) return fmi2Error;
    return nvr == 0 ? fmi2OK : refuse(c, "fmi2SetString: %s", "the FMU has no String variables");
}

/* ------------------------------------------------------------------------------------- FMU state */
/* A state is a copy of the Model; serialised, the bytes of that copy behind a tag and its size (the same
   build of the FMU reads them back: a state is not meant to travel between platforms). */
#define STATE_TAG "brake_car state v1"

fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate) {
    Instance *c = comp;
    if (!allowed(c, "fmi2GetFMUstate", ANY_MODE)) return fmi2Error;
    Model *copy = *FMUstate;
    if (!copy) {
        copy = c->cb->allocateMemory ? c->cb->allocateMemory(1, sizeof(Model)) : calloc(1, sizeof(Model));
        if (!copy) return refuse(c, "fmi2GetFMUstate: %s", "out of memory");
    }
    *copy = c->m;
    *FMUstate = copy;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate FMUstate) {
    Instance *c = comp;
    if (!allowed(c, "fmi2SetFMUstate", ANY_MODE)) return fmi2Error;
    if (!FMUstate) return refuse(c, "fmi2SetFMUstate: %s", "no state given");
    Mode mode = c->m.mode;                  /* the state of the simulation, not of the calling sequence */
    c->m = *(const Model *)FMUstate;
    c->m.mode = mode;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate) {
    Instance *c = comp;
    if (!allowed(c, "fmi2FreeFMUstate", ANY_MODE)) return fmi2Error;
    if (FMUstate && *FMUstate) {
        release(c, *FMUstate);
        *FMUstate = NULL;
    }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate FMUstate, size_t *size) {
    Instance *c = comp;
    (void)FMUstate;
    if (!allowed(c, "fmi2SerializedFMUstateSize", ANY_MODE)) return fmi2Error;
    *size = sizeof STATE_TAG + sizeof(Model);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    Instance *c = comp;
    if (!allowed(c, "fmi2SerializeFMUstate", ANY_MODE)) return fmi2Error;
    if (!FMUstate || size != sizeof STATE_TAG + sizeof(Model))
        return refuse(c, "fmi2SerializeFMUstate: %s", "no state, or a buffer of the wrong size");
    memcpy(serializedState, STATE_TAG, sizeof STATE_TAG);
    memcpy(serializedState + sizeof STATE_TAG, FMUstate, sizeof(Model));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    Instance *c = comp;
    if (!allowed(c, "fmi2DeSerializeFMUstate", ANY_MODE)) return fmi2Error;
    if (size != sizeof STATE_TAG + sizeof(Model) || memcmp(serializedState, STATE_TAG, sizeof STATE_TAG) != 0)
        return refuse(c, "fmi2DeSerializeFMUstate: %s", "not a state of this build of brake_car");
    Model copy;
    memcpy(&copy, serializedState + sizeof STATE_TAG, sizeof copy);
    if (copy.mode < MODE_INSTANTIATED || copy.mode > MODE_ERROR || copy.dump < DUMP_FILL || copy.dump > DUMP_VENT)
        return refuse(c, "fmi2DeSerializeFMUstate: %s", "the state is corrupt");
    fmi2FMUstate state = NULL;
    if (fmi2GetFMUstate(comp, &state) != fmi2OK) return fmi2Error;   /* allocates one */
    *(Model *)state = copy;
    *FMUstate = state;
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    (void)vUnknown_ref; (void)nUnknown; (void)vKnown_ref; (void)nKnown; (void)dvKnown; (void)dvUnknown;
    return refuse(comp, "fmi2GetDirectionalDerivative: %s", "not provided (providesDirectionalDerivative=false)");
}

/* ------------------------------------------------------------------- FMI 2.0: co-simulation functions */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return refuse(comp, "fmi2SetRealInputDerivatives: %s", "inputs are held, not interpolated "
                  "(canInterpolateInputs=false)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return refuse(comp, "fmi2GetRealOutputDerivatives: %s", "not provided (maxOutputDerivativeOrder=0)");
}

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    Instance *c = comp;
    double H = communicationStepSize;
    fmi2Status status = fmi2OK;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!allowed(c, "fmi2DoStep", IN(MODE_STEP))) return fmi2Error;
    if (!(isfinite(H) && H > 0.0 && H <= STEP_MAX_S))
        return refuse(c, "fmi2DoStep: %s must be > 0 and <= 1e6 s", "communicationStepSize");
    if (!isfinite(currentCommunicationPoint))
        return refuse(c, "fmi2DoStep: %s must be finite", "currentCommunicationPoint");
    if (fabs(currentCommunicationPoint - c->m.time_s) > 1e-9 * (1.0 + fabs(c->m.time_s))) {
        log_msg(c, fmi2Warning, "logStatusWarning", "fmi2DoStep: currentCommunicationPoint %.9g is not the "
                "end of the last step %.9g (the model does not depend on time: stepped all the same)",
                currentCommunicationPoint, c->m.time_s);
        status = fmi2Warning;
    }
    /* n = ceil(H / DT_MAX_S) sub-steps of h = H/n <= DT_MAX_S (a step longer by rounding only is one step) */
    double q = H / DT_MAX_S;
    long long n = (long long)q;
    if (q - (double)n > 1e-9) n += 1;
    if (n < 1) n = 1;
    double h = H / (double)n;
    for (long long i = 0; i < n; i++) plant_step(&c->m, h);
    c->m.time_s = currentCommunicationPoint + H;   /* the master's time, not a sum of sub-steps */
    return status;
}

fmi2Status fmi2CancelStep(fmi2Component comp) {
    return refuse(comp, "fmi2CancelStep: %s", "fmi2DoStep never returns fmi2Pending");
}

fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Status *value) {
    (void)s; (void)value;
    log_msg(comp, fmi2Warning, "logStatusWarning", "fmi2GetStatus: %s", "fmi2DoStep never returns fmi2Pending");
    return fmi2Discard;
}

fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *value) {
    Instance *c = comp;
    if (!allowed(c, "fmi2GetRealStatus", ANY_MODE)) return fmi2Error;
    if (s != fmi2LastSuccessfulTime) return fmi2Discard;
    *value = c->m.time_s;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Integer *value) {
    (void)comp; (void)s; (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Boolean *value) {
    Instance *c = comp;
    if (!allowed(c, "fmi2GetBooleanStatus", ANY_MODE)) return fmi2Error;
    if (s != fmi2Terminated) return fmi2Discard;
    *value = fmi2False;                            /* the model never asks to stop */
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind s, fmi2String *value) {
    (void)comp; (void)s; (void)value;
    return fmi2Discard;
}
