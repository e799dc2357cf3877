/* A hydrolink multibody client in C, written from protocol/SPEC.md alone: one body in heave.
 *
 * It owns the body: its mass matrix holds the body's mass plus setup.added_mass (A-infinity, SPEC
 * §5.2 force contract), its stiffness setup.hydrostatic_stiffness, setup.net_buoyancy is a constant
 * force, and each `forces` reply's excitation + radiation is the load. Newmark's average
 * acceleration rule, the predictor recipe of SPEC §8.3 (step k+1 sent once, at the state predicted
 * from t_k). The HDB travels as its original files, by SHA-256 (SPEC §5.1 "HDB file set", §5.8):
 * what the server's store lacks (error 13) is uploaded once and the hello sent again.
 *
 * Only libzmq and msgpack-c (Debian: libzmq3-dev, libmsgpack-dev):
 *
 *   gcc -O2 -o heave heave.c -lzmq -lmsgpackc -lm
 *   ./heave tcp://HOST:PORT SCENE.toml MASS OUT.csv HDB_KEY FORMAT FILE [FILE ...]
 *
 * SCENE.toml: the scene (one wet body, heave active); MASS: the body's mass [kg]; HDB_KEY: the
 * body's `hdb` string in the scene; FORMAT: wamit | bemio | netcdf; FILE: the HDB's files (WAMIT:
 * the run's .1, .3, .hst, ...). OUT.csv: one row per step: seq, time, the position and velocity
 * sent (6 each), the excitation and radiation received (6 each), the wave elevation and the heave
 * displacement the body reached, every number with 17 significant digits.
 * Exit status 0 when the run completed, 2 on any error (said on stderr).
 */
#include <msgpack.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zmq.h>

#define TIMEOUT_MS 60000
#define MAX_FILES 16

/* ------------------------------------------------------------------ SHA-256 (FIPS 180-4) */

static const uint32_t K256[64] = {
    0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4, 0xab1c5ed5,
    0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe, 0x9bdc06a7, 0xc19bf174,
    0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f, 0x4a7484aa, 0x5cb0a9dc, 0x76f988da,
    0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7, 0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967,
    0x27b70a85, 0x2e1b2138, 0x4d2c6dfc, 0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85,
    0xa2bfe8a1, 0xa81a664b, 0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070,
    0x19a4c116, 0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
    0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7, 0xc67178f2};

#define ROTR(x, n) (((x) >> (n)) | ((x) << (32 - (n))))

static void sha256_block(uint32_t h[8], const unsigned char *p) {
    uint32_t w[64], a, b, c, d, e, f, g, hh;
    for (int i = 0; i < 16; i++)
        w[i] = (uint32_t)p[4 * i] << 24 | (uint32_t)p[4 * i + 1] << 16 | (uint32_t)p[4 * i + 2] << 8 | p[4 * i + 3];
    for (int i = 16; i < 64; i++) {
        uint32_t s0 = ROTR(w[i - 15], 7) ^ ROTR(w[i - 15], 18) ^ (w[i - 15] >> 3);
        uint32_t s1 = ROTR(w[i - 2], 17) ^ ROTR(w[i - 2], 19) ^ (w[i - 2] >> 10);
        w[i] = w[i - 16] + s0 + w[i - 7] + s1;
    }
    a = h[0]; b = h[1]; c = h[2]; d = h[3]; e = h[4]; f = h[5]; g = h[6]; hh = h[7];
    for (int i = 0; i < 64; i++) {
        uint32_t t1 = hh + (ROTR(e, 6) ^ ROTR(e, 11) ^ ROTR(e, 25)) + ((e & f) ^ (~e & g)) + K256[i] + w[i];
        uint32_t t2 = (ROTR(a, 2) ^ ROTR(a, 13) ^ ROTR(a, 22)) + ((a & b) ^ (a & c) ^ (b & c));
        hh = g; g = f; f = e; e = d + t1; d = c; c = b; b = a; a = t1 + t2;
    }
    h[0] += a; h[1] += b; h[2] += c; h[3] += d; h[4] += e; h[5] += f; h[6] += g; h[7] += hh;
}

/* the lowercase hex digest of data[0..n) into hex (65 bytes) */
static void sha256_hex(const unsigned char *data, size_t n, char hex[65]) {
    uint32_t h[8] = {0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a, 0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19};
    size_t full = n / 64 * 64;
    for (size_t i = 0; i < full; i += 64) sha256_block(h, data + i);
    unsigned char tail[128] = {0};
    size_t rest = n - full;
    memcpy(tail, data + full, rest);
    tail[rest] = 0x80;
    size_t len = rest + 1 + 8 <= 64 ? 64 : 128;
    uint64_t bits = (uint64_t)n * 8;
    for (int i = 0; i < 8; i++) tail[len - 1 - i] = (unsigned char)(bits >> (8 * i));
    for (size_t i = 0; i < len; i += 64) sha256_block(h, tail + i);
    for (int i = 0; i < 8; i++) snprintf(hex + 8 * i, 9, "%08x", h[i]);
}

/* ------------------------------------------------------------------ SPEC §1, §3: envelope, requests */

typedef struct {
    void *sock;
    char session[128];
    long next_id;
    char id[32];
    msgpack_unpacked reply;
    zmq_msg_t frame;
    msgpack_sbuffer buf;
    msgpack_packer pk;
} link_t;

static void pack_str(msgpack_packer *pk, const char *s) {
    size_t n = strlen(s);
    msgpack_pack_str(pk, n);
    msgpack_pack_str_body(pk, s, n);
}

/* clear the buffer and pack the envelope (§3): v, type, msg_id, session; `extra` entries follow */
static void begin(link_t *ln, const char *type, int extra) {
    msgpack_sbuffer_clear(&ln->buf);
    snprintf(ln->id, sizeof ln->id, "c-%ld", ++ln->next_id);
    msgpack_pack_map(&ln->pk, 4 + extra);
    pack_str(&ln->pk, "v"); msgpack_pack_int(&ln->pk, 1);
    pack_str(&ln->pk, "type"); pack_str(&ln->pk, type);
    pack_str(&ln->pk, "msg_id"); pack_str(&ln->pk, ln->id);
    pack_str(&ln->pk, "session");
    if (ln->session[0]) pack_str(&ln->pk, ln->session); else msgpack_pack_nil(&ln->pk);
}

static int str_eq(const msgpack_object *o, const char *s) {
    return o && o->type == MSGPACK_OBJECT_STR && o->via.str.size == strlen(s) && !memcmp(o->via.str.ptr, s, o->via.str.size);
}

static const msgpack_object *get(const msgpack_object *map, const char *key) {
    if (!map || map->type != MSGPACK_OBJECT_MAP) return NULL;
    for (uint32_t i = 0; i < map->via.map.size; i++)
        if (str_eq(&map->via.map.ptr[i].key, key)) return &map->via.map.ptr[i].val;
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

/* a "<f8" array (§2.1) of exactly n values into out; 0 when it is not one */
static int get_f8(const msgpack_object *arr, double *out, size_t n) {
    const msgpack_object *dt = get(arr, "dtype"), *data = get(arr, "data");
    if (!str_eq(dt, "<f8") || !data || data->type != MSGPACK_OBJECT_BIN || data->via.bin.size != n * 8) return 0;
    memcpy(out, data->via.bin.ptr, n * 8); /* little-endian host (x86-64, aarch64) */
    return 1;
}

/* a (1, 6) "<f8" array map (§2.1) */
static void pack_row6(msgpack_packer *pk, const double *v) {
    msgpack_pack_map(pk, 3);
    pack_str(pk, "dtype"); pack_str(pk, "<f8");
    pack_str(pk, "shape"); msgpack_pack_array(pk, 2); msgpack_pack_int(pk, 1); msgpack_pack_int(pk, 6);
    pack_str(pk, "data"); msgpack_pack_bin(pk, 48); msgpack_pack_bin_body(pk, v, 48);
}

/* send the packed request, return the reply whose parent is its msg_id (§6: others are late) */
static const msgpack_object *request(link_t *ln) {
    if (zmq_send(ln->sock, ln->buf.data, ln->buf.size, 0) < 0) return NULL;
    for (;;) {
        zmq_msg_close(&ln->frame);
        zmq_msg_init(&ln->frame);
        if (zmq_msg_recv(&ln->frame, ln->sock, 0) < 0) return NULL;
        msgpack_unpacked_destroy(&ln->reply);
        msgpack_unpacked_init(&ln->reply);
        if (msgpack_unpack_next(&ln->reply, zmq_msg_data(&ln->frame), zmq_msg_size(&ln->frame), NULL)
            != MSGPACK_UNPACK_SUCCESS) continue;
        if (str_eq(get(&ln->reply.data, "parent"), ln->id)) return &ln->reply.data;
    }
}

static int fail(const char *what, const msgpack_object *r) {
    if (!r) { fprintf(stderr, "heave.c: %s: no reply within %d s\n", what, TIMEOUT_MS / 1000); return 2; }
    const msgpack_object *m = get(r, "message"), *f = get(r, "field");
    double code = 0;
    as_double(get(r, "code"), &code);
    fprintf(stderr, "heave.c: %s: server error %.0f [%.*s]: %.*s\n", what, code,
            f && f->type == MSGPACK_OBJECT_STR ? (int)f->via.str.size : 0, f && f->type == MSGPACK_OBJECT_STR ? f->via.str.ptr : "",
            m && m->type == MSGPACK_OBJECT_STR ? (int)m->via.str.size : 0, m && m->type == MSGPACK_OBJECT_STR ? m->via.str.ptr : "");
    return 2;
}

/* ------------------------------------------------------------------ files */

typedef struct {
    const char *name;   /* the file name alone (the part after the last '/') */
    unsigned char *data;
    size_t size;
    char hash[65];
} file_t;

static unsigned char *read_all(const char *path, size_t *size) {
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    unsigned char *data = malloc(n > 0 ? (size_t)n : 1);
    if (data && fread(data, 1, (size_t)n, f) != (size_t)n) { free(data); data = NULL; }
    fclose(f);
    *size = (size_t)n;
    return data;
}

/* hello (§5.1) with the HDB as a file set by hash; its reply (valid until the next request) */
static const msgpack_object *hello(link_t *ln, const char *scene, const char *key, const char *format,
                                   const file_t *files, int n_files) {
    begin(ln, "hello", 4);
    pack_str(&ln->pk, "role"); pack_str(&ln->pk, "multibody");
    pack_str(&ln->pk, "scene"); pack_str(&ln->pk, scene);
    pack_str(&ln->pk, "hdbs");
    msgpack_pack_map(&ln->pk, 1);
    pack_str(&ln->pk, key);
    msgpack_pack_map(&ln->pk, 2);
    pack_str(&ln->pk, "format"); pack_str(&ln->pk, format);
    pack_str(&ln->pk, "files");
    msgpack_pack_map(&ln->pk, (size_t)n_files);
    for (int i = 0; i < n_files; i++) { pack_str(&ln->pk, files[i].name); pack_str(&ln->pk, files[i].hash); }
    pack_str(&ln->pk, "client");
    msgpack_pack_map(&ln->pk, 2);
    pack_str(&ln->pk, "name"); pack_str(&ln->pk, "hydrolink-c-heave");
    pack_str(&ln->pk, "version"); pack_str(&ln->pk, "1");
    return request(ln);
}

/* upload (§5.8) every file whose hash the error's `missing` lists; the count, or -1 on failure */
static int upload_missing(link_t *ln, const msgpack_object *err, const file_t *files, int n_files) {
    const msgpack_object *missing = get(err, "missing");
    if (!missing || missing->type != MSGPACK_OBJECT_ARRAY) return -1;
    char want[MAX_FILES][65];
    uint32_t n = missing->via.array.size;
    if (n > MAX_FILES) return -1;
    for (uint32_t j = 0; j < n; j++) {   /* copied: the next request reuses the reply buffer */
        const msgpack_object *h = &missing->via.array.ptr[j];
        if (h->type != MSGPACK_OBJECT_STR || h->via.str.size != 64) return -1;
        memcpy(want[j], h->via.str.ptr, 64);
        want[j][64] = 0;
    }
    int sent = 0;
    for (uint32_t j = 0; j < n; j++) {
        int i = 0;
        while (i < n_files && strcmp(files[i].hash, want[j])) i++;
        if (i == n_files) { fprintf(stderr, "heave.c: the server asked for %s, not one of our files\n", want[j]); return -1; }
        begin(ln, "upload", 2);
        pack_str(&ln->pk, "sha256"); pack_str(&ln->pk, files[i].hash);
        pack_str(&ln->pk, "data");
        msgpack_pack_bin(&ln->pk, files[i].size);
        msgpack_pack_bin_body(&ln->pk, files[i].data, files[i].size);
        const msgpack_object *r = request(ln);
        if (!r || !str_eq(get(r, "type"), "uploaded")) { fail("upload", r); return -1; }
        sent++;
    }
    return sent;
}

/* ------------------------------------------------------------------ the body */

int main(int argc, char **argv) {
    if (argc < 8) {
        fprintf(stderr, "usage: %s tcp://HOST:PORT SCENE.toml MASS OUT.csv HDB_KEY FORMAT FILE [FILE ...]\n", argv[0]);
        return 2;
    }
    const char *address = argv[1], *key = argv[5], *format = argv[6];
    double mass = atof(argv[3]);
    size_t scene_size;
    char *scene = (char *)read_all(argv[2], &scene_size);
    if (!scene) { fprintf(stderr, "heave.c: cannot read the scene %s\n", argv[2]); return 2; }
    scene = realloc(scene, scene_size + 1);
    scene[scene_size] = 0;
    int n_files = argc - 7;
    if (n_files > MAX_FILES) { fprintf(stderr, "heave.c: at most %d HDB files\n", MAX_FILES); return 2; }
    file_t files[MAX_FILES];
    for (int i = 0; i < n_files; i++) {
        const char *path = argv[7 + i], *slash = strrchr(path, '/');
        files[i].name = slash ? slash + 1 : path;
        files[i].data = read_all(path, &files[i].size);
        if (!files[i].data) { fprintf(stderr, "heave.c: cannot read the HDB file %s\n", path); return 2; }
        sha256_hex(files[i].data, files[i].size, files[i].hash);
    }
    FILE *out = fopen(argv[4], "w");
    if (!out) { fprintf(stderr, "heave.c: cannot write %s\n", argv[4]); return 2; }

    link_t ln = {0};
    void *ctx = zmq_ctx_new();
    ln.sock = zmq_socket(ctx, ZMQ_DEALER);
    int zero = 0, timeout = TIMEOUT_MS;
    zmq_setsockopt(ln.sock, ZMQ_LINGER, &zero, sizeof zero);
    zmq_setsockopt(ln.sock, ZMQ_RCVTIMEO, &timeout, sizeof timeout);
    if (zmq_connect(ln.sock, address) != 0) { fprintf(stderr, "heave.c: cannot connect to %s\n", address); return 2; }
    msgpack_unpacked_init(&ln.reply);
    zmq_msg_init(&ln.frame);
    msgpack_sbuffer_init(&ln.buf);
    msgpack_packer_init(&ln.pk, &ln.buf, msgpack_sbuffer_write);

    /* hello by hash; on 13 missing_content upload what is missing and say hello again (§5.8) */
    const msgpack_object *r = hello(&ln, scene, key, format, files, n_files);
    double code = 0;
    if (r && str_eq(get(r, "type"), "error") && as_double(get(r, "code"), &code) && code == 13) {
        int sent = upload_missing(&ln, r, files, n_files);
        if (sent < 0) return 2;
        fprintf(stderr, "heave.c: uploaded %d HDB file(s)\n", sent);
        r = hello(&ln, scene, key, format, files, n_files);
    }
    if (!r || !str_eq(get(r, "type"), "welcome")) return fail("hello", r);
    const msgpack_object *sid = get(r, "session"), *setup = get(r, "setup");
    snprintf(ln.session, sizeof ln.session, "%.*s", (int)sid->via.str.size, sid->via.str.ptr);

    /* the setup (§5.1): one wet body, heave its active DOF */
    double a_inf[36], stiffness[36], x_eq[6], buoyancy, dt, last;
    if (!get_f8(get(setup, "added_mass"), a_inf, 36) || !get_f8(get(setup, "hydrostatic_stiffness"), stiffness, 36)
        || !get_f8(get(setup, "equilibrium_position"), x_eq, 6) || !get_f8(get(setup, "net_buoyancy"), &buoyancy, 1)
        || !as_double(get(setup, "dt"), &dt) || !as_double(get(setup, "last_seq"), &last)) {
        fprintf(stderr, "heave.c: the setup is not one wet body's (bodies, added_mass 6x6, ...)\n");
        return 2;
    }
    const double m = mass + a_inf[14], k = stiffness[14], h = dt;   /* heave row and column: index 2*6+2 */
    const double newmark = m + 0.25 * h * h * k;

    /* lockstep (§8.3, predictor): the step of t_k+1 sent at the state predicted from t_k */
    double u = 0.0, v = 0.0, a = 0.0, pos[6], vel[6] = {0}, ex[6], rad[6], eta = 0.0;
    for (long seq = 0; seq <= (long)last; seq++) {
        double up = seq ? u + h * v + 0.5 * h * h * a : 0.0, vp = seq ? v + h * a : 0.0;
        memcpy(pos, x_eq, sizeof pos);
        pos[2] += up;
        vel[2] = vp;
        begin(&ln, "step", 5);
        pack_str(&ln.pk, "seq"); msgpack_pack_int64(&ln.pk, seq);
        pack_str(&ln.pk, "time"); msgpack_pack_double(&ln.pk, seq * h);
        pack_str(&ln.pk, "iteration"); msgpack_pack_int(&ln.pk, 0);
        pack_str(&ln.pk, "position"); pack_row6(&ln.pk, pos);
        pack_str(&ln.pk, "velocity"); pack_row6(&ln.pk, vel);
        r = request(&ln);
        if (!r || !str_eq(get(r, "type"), "forces")) return fail("step", r);
        if (!get_f8(get(r, "excitation"), ex, 6) || !get_f8(get(r, "radiation"), rad, 6)
            || !as_double(get(r, "wave_elevation"), &eta)) {
            fprintf(stderr, "heave.c: step %ld: a forces reply without excitation/radiation/wave_elevation\n", seq);
            return 2;
        }
        double f = ex[2] + rad[2] + buoyancy;
        if (seq == 0) {
            a = (f - k * u) / m;
        } else {
            double a_new = (f - k * (u + h * v + 0.25 * h * h * a)) / newmark;
            u += h * v + 0.25 * h * h * (a + a_new);
            v += 0.5 * h * (a + a_new);
            a = a_new;
        }
        fprintf(out, "%ld,%.17g", seq, seq * h);
        for (int i = 0; i < 6; i++) fprintf(out, ",%.17g", pos[i]);
        for (int i = 0; i < 6; i++) fprintf(out, ",%.17g", vel[i]);
        for (int i = 0; i < 6; i++) fprintf(out, ",%.17g", ex[i]);
        for (int i = 0; i < 6; i++) fprintf(out, ",%.17g", rad[i]);
        fprintf(out, ",%.17g,%.17g\n", eta, u);
    }
    fclose(out);
    begin(&ln, "bye", 0);
    r = request(&ln);
    if (!r || !str_eq(get(r, "type"), "goodbye")) return fail("bye", r);
    zmq_close(ln.sock);
    zmq_ctx_term(ctx);
    return 0;
}
