/* A hydrolink controller in C (SPEC §5.7): reactive spring-damper force control, F = c v + k x.
 *
 * The twin of examples/controllers/reactive.py: the same formula in the same order of operations,
 * so (built without floating-point contraction) its commands, and the run, are bit-identical.
 * Only libzmq and msgpack-c (Debian: libzmq3-dev, libmsgpack-dev):
 *
 *   gcc -O2 -ffp-contract=off -o reactive reactive.c -lzmq -lmsgpackc
 *   ./reactive tcp://HOST:PORT TOKEN [SESSION|-] [NAME]
 *
 * TOKEN: the session's join token (SPEC §5.7.2), as hydrolink run prints it or was given it.
 *
 * Parameters from the scene's [[controllers]] parameters: damping, stiffness (numbers).
 * Exit status 0 when the run ended (stop), 2 when the server refused or went silent.
 */
#include <msgpack.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <zmq.h>

#define MAX_PTOS 64
#define WAIT_S 1.0
#define TIMEOUT_S 30.0

typedef struct {
    void *sock;
    char session[128];
    long next_id;
    char id[32];
    msgpack_unpacked reply;
    zmq_msg_t frame;
} link_t;

static void pack_str(msgpack_packer *pk, const char *s) {
    size_t n = strlen(s);
    msgpack_pack_str(pk, n);
    msgpack_pack_str_body(pk, s, n);
}

/* the envelope: v, type, msg_id, session; then `extra` more entries follow (the caller packs them) */
static void pack_envelope(link_t *ln, msgpack_packer *pk, const char *type, int extra) {
    snprintf(ln->id, sizeof ln->id, "c-%ld", ++ln->next_id);
    msgpack_pack_map(pk, 4 + extra);
    pack_str(pk, "v");
    msgpack_pack_int(pk, 1);
    pack_str(pk, "type");
    pack_str(pk, type);
    pack_str(pk, "msg_id");
    pack_str(pk, ln->id);
    pack_str(pk, "session");
    if (ln->session[0]) pack_str(pk, ln->session); else msgpack_pack_nil(pk);
}

static int key_is(const msgpack_object *k, const char *s) {
    return k->type == MSGPACK_OBJECT_STR && k->via.str.size == strlen(s) && !memcmp(k->via.str.ptr, s, k->via.str.size);
}

static const msgpack_object *get(const msgpack_object *map, const char *key) {
    if (!map || map->type != MSGPACK_OBJECT_MAP) return NULL;
    for (uint32_t i = 0; i < map->via.map.size; i++)
        if (key_is(&map->via.map.ptr[i].key, key)) return &map->via.map.ptr[i].val;
    return NULL;
}

static int as_double(const msgpack_object *o, double *out) {
    if (!o) return 0;
    switch (o->type) {
    case MSGPACK_OBJECT_FLOAT64: case MSGPACK_OBJECT_FLOAT32: *out = o->via.f64; return 1;
    case MSGPACK_OBJECT_POSITIVE_INTEGER: *out = (double)o->via.u64; return 1;
    case MSGPACK_OBJECT_NEGATIVE_INTEGER: *out = (double)o->via.i64; return 1;
    default: return 0;
    }
}

static int as_int(const msgpack_object *o, long *out) {
    if (!o) return 0;
    if (o->type == MSGPACK_OBJECT_POSITIVE_INTEGER) { *out = (long)o->via.u64; return 1; }
    if (o->type == MSGPACK_OBJECT_NEGATIVE_INTEGER) { *out = (long)o->via.i64; return 1; }
    return 0;
}

static int str_eq(const msgpack_object *o, const char *s) {
    return o && o->type == MSGPACK_OBJECT_STR && o->via.str.size == strlen(s) && !memcmp(o->via.str.ptr, s, o->via.str.size);
}

/* a float64 array (SPEC §2.1: {"dtype": "<f8", "shape": [...], "data": bin}) -> n values */
static long get_f8(const msgpack_object *arr, double *out, long max) {
    const msgpack_object *dt = get(arr, "dtype"), *data = get(arr, "data");
    if (!str_eq(dt, "<f8") || !data || data->type != MSGPACK_OBJECT_BIN) return -1;
    long n = (long)(data->via.bin.size / 8);
    if (n > max) return -1;
    memcpy(out, data->via.bin.ptr, (size_t)n * 8); /* little-endian host (x86-64, aarch64) */
    return n;
}

/* send the packed buffer, wait for the reply whose parent is our msg_id; NULL on timeout */
static const msgpack_object *request(link_t *ln, msgpack_sbuffer *buf, double wait) {
    if (zmq_send(ln->sock, buf->data, buf->size, 0) < 0) return NULL;
    int ms = (int)((wait + TIMEOUT_S) * 1000);
    zmq_setsockopt(ln->sock, ZMQ_RCVTIMEO, &ms, sizeof ms);
    for (;;) {
        zmq_msg_close(&ln->frame);
        zmq_msg_init(&ln->frame);
        if (zmq_msg_recv(&ln->frame, ln->sock, 0) < 0) return NULL;
        msgpack_unpacked_destroy(&ln->reply);
        msgpack_unpacked_init(&ln->reply);
        if (msgpack_unpack_next(&ln->reply, zmq_msg_data(&ln->frame), zmq_msg_size(&ln->frame), NULL)
            != MSGPACK_UNPACK_SUCCESS) continue;
        const msgpack_object *parent = get(&ln->reply.data, "parent");
        if (str_eq(parent, ln->id)) return &ln->reply.data;
    }
}

static void print_error(const msgpack_object *r) {
    const msgpack_object *m = get(r, "message"), *f = get(r, "field");
    long code = 0;
    as_int(get(r, "code"), &code);
    fprintf(stderr, "reactive.c: server error %ld [%.*s]: %.*s\n", code,
            f && f->type == MSGPACK_OBJECT_STR ? (int)f->via.str.size : 0, f && f->type == MSGPACK_OBJECT_STR ? f->via.str.ptr : "",
            m && m->type == MSGPACK_OBJECT_STR ? (int)m->via.str.size : 0, m && m->type == MSGPACK_OBJECT_STR ? m->via.str.ptr : "");
}

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: %s tcp://HOST:PORT TOKEN [SESSION|-] [NAME]\n", argv[0]);
        return 2;
    }
    const char *token = argv[2];
    const char *name = argc > 4 ? argv[4] : NULL;
    link_t ln = {0};
    void *ctx = zmq_ctx_new();
    ln.sock = zmq_socket(ctx, ZMQ_DEALER);
    int zero = 0;
    zmq_setsockopt(ln.sock, ZMQ_LINGER, &zero, sizeof zero);
    if (zmq_connect(ln.sock, argv[1]) != 0) { fprintf(stderr, "reactive.c: cannot connect to %s\n", argv[1]); return 2; }
    if (argc > 3 && strcmp(argv[3], "-")) snprintf(ln.session, sizeof ln.session, "%s", argv[3]);
    msgpack_unpacked_init(&ln.reply);
    zmq_msg_init(&ln.frame);
    msgpack_sbuffer buf;
    msgpack_sbuffer_init(&buf);
    msgpack_packer pk;
    msgpack_packer_init(&pk, &buf, msgpack_sbuffer_write);

    /* hello, retried while no session declares the controller yet (error 7), for up to 30 s */
    const msgpack_object *r = NULL;
    for (int attempt = 0;; attempt++) {
        msgpack_sbuffer_clear(&buf);
        pack_envelope(&ln, &pk, "hello", 4);
        pack_str(&pk, "role"); pack_str(&pk, "controller");
        pack_str(&pk, "token"); pack_str(&pk, token);
        pack_str(&pk, "controller"); if (name) pack_str(&pk, name); else msgpack_pack_nil(&pk);
        pack_str(&pk, "client");
        msgpack_pack_map(&pk, 2);
        pack_str(&pk, "name"); pack_str(&pk, "hydrolink-c-reactive");
        pack_str(&pk, "version"); pack_str(&pk, "1");
        r = request(&ln, &buf, 0.0);
        if (!r) { fprintf(stderr, "reactive.c: no reply from %s\n", argv[1]); return 2; }
        if (str_eq(get(r, "type"), "welcome")) break;
        long code = 0;
        as_int(get(r, "code"), &code);
        if (code == 7 && !ln.session[0] && attempt < 300) {
            struct timespec ts = {0, 100000000};
            nanosleep(&ts, NULL);
            continue;
        }
        print_error(r);
        return 2;
    }
    const msgpack_object *s = get(r, "session"), *ctl = get(r, "control");
    snprintf(ln.session, sizeof ln.session, "%.*s", (int)s->via.str.size, s->via.str.ptr);
    long epoch = 0;
    as_int(get(r, "epoch"), &epoch);
    double c = 0.0, k = 0.0;
    const msgpack_object *params = get(ctl, "parameters");
    if (!as_double(get(params, "damping"), &c) || !as_double(get(params, "stiffness"), &k)) {
        fprintf(stderr, "reactive.c: parameters damping and stiffness are required\n");
        return 2;
    }
    const msgpack_object *nm = get(ctl, "name"), *ptos = get(ctl, "ptos");
    char my_name[128], pto[MAX_PTOS][128];
    snprintf(my_name, sizeof my_name, "%.*s", (int)nm->via.str.size, nm->via.str.ptr);
    uint32_t n_pto = ptos->via.array.size;
    if (n_pto > MAX_PTOS) return 2;
    for (uint32_t i = 0; i < n_pto; i++)
        snprintf(pto[i], sizeof pto[i], "%.*s", (int)ptos->via.array.ptr[i].via.str.size, ptos->via.array.ptr[i].via.str.ptr);

    double v[MAX_PTOS], x[MAX_PTOS];
    long steps = 0;
    int measure = 1;   /* next request: measure (1) or command (0) */
    long step = 0;
    double force[MAX_PTOS];
    for (;;) {
        msgpack_sbuffer_clear(&buf);
        pack_envelope(&ln, &pk, measure ? "measure" : "command", measure ? 3 : 5);
        pack_str(&pk, "controller"); pack_str(&pk, my_name);
        pack_str(&pk, "epoch"); msgpack_pack_int64(&pk, epoch);
        pack_str(&pk, "wait"); msgpack_pack_double(&pk, WAIT_S);
        if (!measure) {
            pack_str(&pk, "step"); msgpack_pack_int64(&pk, step);
            pack_str(&pk, "commands");
            msgpack_pack_map(&pk, n_pto);
            for (uint32_t i = 0; i < n_pto; i++) {
                pack_str(&pk, pto[i]);
                msgpack_pack_map(&pk, 1);
                pack_str(&pk, "force");
                msgpack_pack_double(&pk, force[i]);
            }
        }
        r = request(&ln, &buf, WAIT_S);
        if (!r) { fprintf(stderr, "reactive.c: the server went silent\n"); return 2; }
        const msgpack_object *type = get(r, "type");
        if (str_eq(type, "measurements")) {
            if (!as_int(get(r, "step"), &step) || get_f8(get(r, "pto_velocity"), v, MAX_PTOS) != (long)n_pto
                || get_f8(get(r, "pto_displacement"), x, MAX_PTOS) != (long)n_pto) {
                fprintf(stderr, "reactive.c: measurements need pto_velocity and pto_displacement\n");
                return 2;
            }
            for (uint32_t i = 0; i < n_pto; i++) force[i] = c * v[i] + k * x[i];
            steps++;
            measure = 0;
        } else if (str_eq(type, "idle")) {
            measure = 1;
        } else if (str_eq(type, "stop")) {
            break;
        } else {
            print_error(r);
            long code = 0;
            as_int(get(r, "code"), &code);
            if (code == 7 || code == 10 || code == 2) return 2;
            measure = 1;
        }
    }
    fprintf(stderr, "reactive.c: done, %ld steps\n", steps);
    msgpack_sbuffer_destroy(&buf);
    msgpack_unpacked_destroy(&ln.reply);
    zmq_msg_close(&ln.frame);
    zmq_close(ln.sock);
    zmq_ctx_term(ctx);
    return 0;
}
