/* The native hydrolink FMU's core (see hydro_core.h). Self-contained C99 + POSIX sockets:
 * a msgpack writer and reader, a ZMTP 3.0 DEALER over TCP (NULL mechanism), SHA-256, and the
 * session of protocol/SPEC.md: hello with the HDB files by hash (§5.1, §5.8), step (§5.2, §5.3),
 * save/restore/release (§5.9), bye. Errors are logged with what failed and returned, never raised. */
#define _POSIX_C_SOURCE 200809L
#include "hydro_core.h"

#include <errno.h>
#include <math.h>
#include <netdb.h>
#include <poll.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>

#define MAX_HDB 16
#define MAX_FILES 16

/* ------------------------------------------------------------------ the instance */

typedef struct {
    char *key, *format;
    int n_files;
    char *names[MAX_FILES];       /* the file names sent */
    unsigned char *data[MAX_FILES];
    size_t size[MAX_FILES];
    char hash[MAX_FILES][65];
} hdb_t;

typedef struct {                  /* what a saved FMU state holds besides the server's state id */
    long seq, iteration;
    int evaluated;                /* the outputs hold the server's answer for the inputs `sent` */
} clock_t_;

struct hl_fmu {
    hl_log_fn log;
    void *env;
    char name[128];
    /* from the export (resources/hydrolink_native.cfg) */
    double dt;
    int n_bodies, na;
    int *flat;                    /* active DOF i -> index in 6N */
    double *equilibrium;          /* 6N */
    double *net_buoyancy;         /* na: constant force part (heave rows) */
    double *a_inf;                /* na x na: the added mass the importer's mass matrix holds */
    double *k_hs;                 /* na x na: the hydrostatic stiffness (dynamic route) */
    char *scene;
    int n_hdb;
    hdb_t hdb[MAX_HDB];
    /* parameters */
    char server[512];
    double timeout;
    /* inputs, outputs, the step */
    double *x, *v, *sent;         /* na, na, 2 na */
    double *out;                  /* 5 na: force, excitation, radiation, hydrostatic, dynamic */
    double eta;
    clock_t_ clk;
    /* the session */
    int sock;
    char session[128];
    long next_id;
    char msg_id[32];
    int failed;                   /* a fatal error happened: every later call fails */
    int closing;                  /* bye: no reconnect, no error if the server is gone */
    double *pos6, *vel6;          /* 6N scratch */
};

void hl_log(hl_fmu *f, int level, const char *fmt, ...) {
    char buf[2048];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    if (f && f->log) f->log(f->env, level, buf);
}

/* ------------------------------------------------------------------ files and the configuration */

static unsigned char *read_file(const char *path, size_t *size) {
    FILE *fp = fopen(path, "rb");
    if (!fp) return NULL;
    if (fseek(fp, 0, SEEK_END) != 0) { fclose(fp); return NULL; }
    long n = ftell(fp);
    rewind(fp);
    unsigned char *data = n >= 0 ? malloc((size_t)n + 1) : NULL;
    if (data && fread(data, 1, (size_t)n, fp) != (size_t)n) { free(data); data = NULL; }
    fclose(fp);
    if (data) { data[n] = 0; *size = (size_t)n; }
    return data;
}

static void sha256_hex(const unsigned char *data, size_t n, char hex[65]);

static char *dupstr(const char *s) {
    size_t n = strlen(s);
    char *d = malloc(n + 1);
    if (d) memcpy(d, s, n + 1);
    return d;
}

static int parse_doubles(const char *s, double *out, int n) {
    char *end;
    for (int i = 0; i < n; i++) {
        out[i] = strtod(s, &end);
        if (end == s) return -1;
        s = end;
    }
    return 0;
}

/* resources/hydrolink_native.cfg: one "tag value" per line (written by clients/fmu/native.py) */
static int read_config(hl_fmu *f, const char *res) {
    char path[4096];
    size_t size;
    snprintf(path, sizeof path, "%s/hydrolink_native.cfg", res);
    char *text = (char *)read_file(path, &size);
    if (!text) { hl_log(f, 1, "cannot read %s: %s", path, strerror(errno)); return -1; }
    hdb_t *h = NULL;
    int ok = 0;
    for (char *line = text, *next; line && *line; line = next) {
        next = strchr(line, '\n');
        if (next) *next++ = 0;
        char *value = strchr(line, ' ');
        if (!value) continue;
        *value++ = 0;
        if (!strcmp(line, "dt")) f->dt = strtod(value, NULL);
        else if (!strcmp(line, "n_bodies")) f->n_bodies = atoi(value);
        else if (!strcmp(line, "active")) {
            char *end;
            f->na = (int)strtol(value, &end, 10);
            if (f->na <= 0 || f->n_bodies <= 0) goto bad;
            f->flat = calloc((size_t)f->na, sizeof(int));
            if (!f->flat) goto bad;
            for (int i = 0; i < f->na; i++) {
                f->flat[i] = (int)strtol(end, &end, 10);
                if (f->flat[i] < 0 || f->flat[i] >= 6 * f->n_bodies) goto bad;   /* an index into 6N */
            }
        } else if (!strcmp(line, "equilibrium")) {
            f->equilibrium = calloc((size_t)(6 * f->n_bodies), sizeof(double));
            if (!f->equilibrium || parse_doubles(value, f->equilibrium, 6 * f->n_bodies)) goto bad;
        } else if (!strcmp(line, "net_buoyancy")) {
            f->net_buoyancy = calloc((size_t)f->na, sizeof(double));
            if (!f->net_buoyancy || parse_doubles(value, f->net_buoyancy, f->na)) goto bad;
        } else if (!strcmp(line, "added_mass")) {
            f->a_inf = calloc((size_t)(f->na * f->na), sizeof(double));
            if (!f->a_inf || parse_doubles(value, f->a_inf, f->na * f->na)) goto bad;
        } else if (!strcmp(line, "hydrostatic_stiffness")) {
            f->k_hs = calloc((size_t)(f->na * f->na), sizeof(double));
            if (!f->k_hs || parse_doubles(value, f->k_hs, f->na * f->na)) goto bad;
        } else if (!strcmp(line, "scene")) {
            snprintf(path, sizeof path, "%s/%s", res, value);
            f->scene = (char *)read_file(path, &size);
            if (!f->scene) { hl_log(f, 1, "cannot read the scene %s: %s", path, strerror(errno)); goto fail; }
        } else if (!strcmp(line, "hdb_key")) {
            if (f->n_hdb == MAX_HDB) goto bad;
            h = &f->hdb[f->n_hdb++];
            h->key = dupstr(value);
        } else if (!strcmp(line, "hdb_format") && h) h->format = dupstr(value);
        else if (!strcmp(line, "hdb_file") && h) {
            if (h->n_files == MAX_FILES) goto bad;
            int k = h->n_files++;
            snprintf(path, sizeof path, "%s/%s", res, value);
            h->data[k] = read_file(path, &h->size[k]);
            if (!h->data[k]) { hl_log(f, 1, "cannot read the HDB file %s: %s", path, strerror(errno)); goto fail; }
            const char *slash = strrchr(value, '/');
            h->names[k] = dupstr(slash ? slash + 1 : value);
            sha256_hex(h->data[k], h->size[k], h->hash[k]);
        }
    }
    ok = f->dt > 0 && f->na > 0 && f->flat && f->equilibrium && f->net_buoyancy && f->a_inf && f->k_hs && f->scene && f->n_hdb > 0;
    if (!ok) goto bad;
    free(text);
    return 0;
bad:
    hl_log(f, 1, "%s/hydrolink_native.cfg is incomplete or malformed (export the FMU again)", res);
fail:
    free(text);
    return -1;
}

hl_fmu *hl_new(const char *resources, const char *name, hl_log_fn log, void *env) {
    hl_fmu *f = calloc(1, sizeof *f);
    if (!f) return NULL;
    f->log = log;
    f->env = env;
    f->sock = -1;
    f->timeout = 30.0;
    snprintf(f->name, sizeof f->name, "%s", name ? name : "hydrolink");
    if (read_config(f, resources)) { hl_free(f); return NULL; }
    f->x = calloc((size_t)f->na, sizeof(double));
    f->v = calloc((size_t)f->na, sizeof(double));
    f->sent = calloc((size_t)(2 * f->na), sizeof(double));
    f->out = calloc((size_t)(5 * f->na), sizeof(double));
    f->pos6 = calloc((size_t)(6 * f->n_bodies), sizeof(double));
    f->vel6 = calloc((size_t)(6 * f->n_bodies), sizeof(double));
    if (!f->x || !f->v || !f->sent || !f->out || !f->pos6 || !f->vel6) {
        hl_log(f, 1, "out of memory creating the FMU instance");
        hl_free(f);
        return NULL;
    }
    return f;
}

static void close_socket(hl_fmu *f) {
    if (f->sock >= 0) close(f->sock);
    f->sock = -1;
}

void hl_free(hl_fmu *f) {
    if (!f) return;
    close_socket(f);
    for (int i = 0; i < f->n_hdb; i++) {
        free(f->hdb[i].key);
        free(f->hdb[i].format);
        for (int k = 0; k < f->hdb[i].n_files; k++) { free(f->hdb[i].names[k]); free(f->hdb[i].data[k]); }
    }
    free(f->flat); free(f->equilibrium); free(f->net_buoyancy); free(f->a_inf); free(f->k_hs); free(f->scene);
    free(f->x); free(f->v); free(f->sent); free(f->out); free(f->pos6); free(f->vel6);
    free(f);
}

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
    uint32_t w[64], a, b, c, d, e, g, k, hh;
    for (int i = 0; i < 16; i++)
        w[i] = (uint32_t)p[4 * i] << 24 | (uint32_t)p[4 * i + 1] << 16 | (uint32_t)p[4 * i + 2] << 8 | p[4 * i + 3];
    for (int i = 16; i < 64; i++)
        w[i] = w[i - 16] + (ROTR(w[i - 15], 7) ^ ROTR(w[i - 15], 18) ^ (w[i - 15] >> 3)) + w[i - 7]
             + (ROTR(w[i - 2], 17) ^ ROTR(w[i - 2], 19) ^ (w[i - 2] >> 10));
    a = h[0]; b = h[1]; c = h[2]; d = h[3]; e = h[4]; g = h[5]; k = h[6]; hh = h[7];
    for (int i = 0; i < 64; i++) {
        uint32_t t1 = hh + (ROTR(e, 6) ^ ROTR(e, 11) ^ ROTR(e, 25)) + ((e & g) ^ (~e & k)) + K256[i] + w[i];
        uint32_t t2 = (ROTR(a, 2) ^ ROTR(a, 13) ^ ROTR(a, 22)) + ((a & b) ^ (a & c) ^ (b & c));
        hh = k; k = g; g = e; e = d + t1; d = c; c = b; b = a; a = t1 + t2;
    }
    h[0] += a; h[1] += b; h[2] += c; h[3] += d; h[4] += e; h[5] += g; h[6] += k; h[7] += hh;
}

static void sha256_hex(const unsigned char *data, size_t n, char hex[65]) {
    uint32_t h[8] = {0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a, 0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19};
    size_t full = n / 64 * 64;
    for (size_t i = 0; i < full; i += 64) sha256_block(h, data + i);
    unsigned char tail[128] = {0};
    size_t rest = n - full, len = rest + 9 <= 64 ? 64 : 128;
    memcpy(tail, data + full, rest);
    tail[rest] = 0x80;
    for (int i = 0; i < 8; i++) tail[len - 1 - i] = (unsigned char)(((uint64_t)n * 8) >> (8 * i));
    for (size_t i = 0; i < len; i += 64) sha256_block(h, tail + i);
    for (int i = 0; i < 8; i++) snprintf(hex + 8 * i, 9, "%08x", h[i]);
}

/* ------------------------------------------------------------------ msgpack: writer */

typedef struct { unsigned char *p; size_t n, cap; int oom; } buf_t;

static void put(buf_t *b, const void *data, size_t n) {
    if (b->oom) return;
    if (b->n + n > b->cap) {
        size_t cap = b->cap ? b->cap : 1024;
        while (cap < b->n + n) cap *= 2;
        unsigned char *p = realloc(b->p, cap);
        if (!p) { b->oom = 1; return; }
        b->p = p;
        b->cap = cap;
    }
    memcpy(b->p + b->n, data, n);
    b->n += n;
}

static void put_be(buf_t *b, uint64_t v, int bytes) {
    unsigned char t[8];
    for (int i = 0; i < bytes; i++) t[i] = (unsigned char)(v >> (8 * (bytes - 1 - i)));
    put(b, t, (size_t)bytes);
}

static void head(buf_t *b, unsigned char fix, unsigned fixmax, unsigned char c16, unsigned char c32, size_t n) {
    unsigned char c;
    if (n <= fixmax) { c = (unsigned char)(fix | n); put(b, &c, 1); }
    else if (n <= 0xffff) { put(b, &c16, 1); put_be(b, n, 2); }
    else { put(b, &c32, 1); put_be(b, n, 4); }
}

static void mp_map(buf_t *b, size_t n) { head(b, 0x80, 15, 0xde, 0xdf, n); }
static void mp_arr(buf_t *b, size_t n) { head(b, 0x90, 15, 0xdc, 0xdd, n); }
static void mp_strn(buf_t *b, const char *s, size_t n) {
    unsigned char c;
    if (n <= 31) { c = (unsigned char)(0xa0 | n); put(b, &c, 1); }
    else if (n <= 0xff) { c = 0xd9; put(b, &c, 1); put_be(b, n, 1); }
    else if (n <= 0xffff) { c = 0xda; put(b, &c, 1); put_be(b, n, 2); }
    else { c = 0xdb; put(b, &c, 1); put_be(b, n, 4); }
    put(b, s, n);
}
static void mp_str(buf_t *b, const char *s) { mp_strn(b, s, strlen(s)); }
static void mp_nil(buf_t *b) { unsigned char c = 0xc0; put(b, &c, 1); }
static void mp_int(buf_t *b, int64_t v) {
    unsigned char c = 0xd3;
    if (v >= 0 && v <= 127) { c = (unsigned char)v; put(b, &c, 1); return; }
    put(b, &c, 1);
    put_be(b, (uint64_t)v, 8);
}
static void mp_f64(buf_t *b, double v) {
    unsigned char c = 0xcb;
    uint64_t u;
    memcpy(&u, &v, 8);
    put(b, &c, 1);
    put_be(b, u, 8);
}
static void mp_bin(buf_t *b, const void *data, size_t n) {
    unsigned char c;
    if (n <= 0xff) { c = 0xc4; put(b, &c, 1); put_be(b, n, 1); }
    else if (n <= 0xffff) { c = 0xc5; put(b, &c, 1); put_be(b, n, 2); }
    else { c = 0xc6; put(b, &c, 1); put_be(b, n, 4); }
    put(b, data, n);
}
/* an (rows, 6) "<f8" array map (SPEC §2.1); the host is little-endian (x86-64, aarch64) */
static void mp_rows6(buf_t *b, const double *v, int rows) {
    mp_map(b, 3);
    mp_str(b, "dtype"); mp_str(b, "<f8");
    mp_str(b, "shape"); mp_arr(b, 2); mp_int(b, rows); mp_int(b, 6);
    mp_str(b, "data"); mp_bin(b, v, (size_t)rows * 48);
}

/* ------------------------------------------------------------------ msgpack: reader (a reply, checked) */

enum { T_NIL, T_BOOL, T_INT, T_FLOAT, T_STR, T_BIN, T_ARR, T_MAP, T_OTHER };
typedef struct node { int type; int64_t i; double f; const unsigned char *p; uint32_t n; struct node *kids; } node_t;
typedef struct { const unsigned char *p, *end; node_t *pool; size_t used, cap; int bad; } rd_t;

static uint64_t get_be(rd_t *r, int bytes) {
    uint64_t v = 0;
    if (r->end - r->p < bytes) { r->bad = 1; return 0; }
    for (int i = 0; i < bytes; i++) v = v << 8 | *r->p++;
    return v;
}

static node_t *alloc_nodes(rd_t *r, size_t n) {
    if (n > (size_t)(r->end - r->p) + 1 || r->used + n > r->cap) { r->bad = 1; return NULL; }
    node_t *k = r->pool + r->used;
    r->used += n;
    return k;
}

static void parse(rd_t *r, node_t *o, int depth) {
    memset(o, 0, sizeof *o);
    if (depth > 32 || r->p >= r->end) { r->bad = 1; return; }
    unsigned c = *r->p++;
    uint64_t n = 0;
    if (c <= 0x7f) { o->type = T_INT; o->i = c; return; }
    if (c >= 0xe0) { o->type = T_INT; o->i = (int8_t)c; return; }
    if ((c & 0xe0) == 0xa0) { o->type = T_STR; n = c & 0x1f; goto bytes; }
    if ((c & 0xf0) == 0x90) { o->type = T_ARR; n = c & 0x0f; goto items; }
    if ((c & 0xf0) == 0x80) { o->type = T_MAP; n = c & 0x0f; goto items; }
    switch (c) {
    case 0xc0: o->type = T_NIL; return;
    case 0xc2: case 0xc3: o->type = T_BOOL; o->i = c == 0xc3; return;
    case 0xcc: o->type = T_INT; o->i = (int64_t)get_be(r, 1); return;
    case 0xcd: o->type = T_INT; o->i = (int64_t)get_be(r, 2); return;
    case 0xce: o->type = T_INT; o->i = (int64_t)get_be(r, 4); return;
    case 0xcf: o->type = T_INT; o->i = (int64_t)get_be(r, 8); return;
    case 0xd0: o->type = T_INT; o->i = (int8_t)get_be(r, 1); return;
    case 0xd1: o->type = T_INT; o->i = (int16_t)get_be(r, 2); return;
    case 0xd2: o->type = T_INT; o->i = (int32_t)get_be(r, 4); return;
    case 0xd3: o->type = T_INT; o->i = (int64_t)get_be(r, 8); return;
    case 0xca: { uint32_t u = (uint32_t)get_be(r, 4); float x; memcpy(&x, &u, 4); o->type = T_FLOAT; o->f = x; return; }
    case 0xcb: { uint64_t u = get_be(r, 8); memcpy(&o->f, &u, 8); o->type = T_FLOAT; return; }
    case 0xd9: o->type = T_STR; n = get_be(r, 1); goto bytes;
    case 0xda: o->type = T_STR; n = get_be(r, 2); goto bytes;
    case 0xdb: o->type = T_STR; n = get_be(r, 4); goto bytes;
    case 0xc4: o->type = T_BIN; n = get_be(r, 1); goto bytes;
    case 0xc5: o->type = T_BIN; n = get_be(r, 2); goto bytes;
    case 0xc6: o->type = T_BIN; n = get_be(r, 4); goto bytes;
    case 0xdc: o->type = T_ARR; n = get_be(r, 2); goto items;
    case 0xdd: o->type = T_ARR; n = get_be(r, 4); goto items;
    case 0xde: o->type = T_MAP; n = get_be(r, 2); goto items;
    case 0xdf: o->type = T_MAP; n = get_be(r, 4); goto items;
    default: r->bad = 1; return;   /* ext types: never in a hydrolink reply */
    }
bytes:
    if ((uint64_t)(r->end - r->p) < n) { r->bad = 1; return; }
    o->p = r->p; o->n = (uint32_t)n; r->p += n;
    return;
items:
    o->n = (uint32_t)n;
    size_t count = o->type == T_MAP ? 2 * (size_t)n : (size_t)n;
    o->kids = alloc_nodes(r, count);
    for (size_t i = 0; i < count && !r->bad; i++) parse(r, &o->kids[i], depth + 1);
}

static int is_str(const node_t *o, const char *s) {
    return o && o->type == T_STR && o->n == strlen(s) && !memcmp(o->p, s, o->n);
}

static const node_t *get(const node_t *map, const char *key) {
    if (!map || map->type != T_MAP) return NULL;
    for (uint32_t i = 0; i < map->n; i++)
        if (is_str(&map->kids[2 * i], key)) return &map->kids[2 * i + 1];
    return NULL;
}

static int num(const node_t *o, double *out) {
    if (!o) return 0;
    if (o->type == T_FLOAT) { *out = o->f; return 1; }
    if (o->type == T_INT) { *out = (double)o->i; return 1; }
    return 0;
}

/* a "<f8" array of exactly n values */
static int f8(const node_t *arr, double *out, size_t n) {
    const node_t *d = get(arr, "data");
    if (!is_str(get(arr, "dtype"), "<f8") || !d || d->type != T_BIN || d->n != n * 8) return 0;
    memcpy(out, d->p, n * 8);
    return 1;
}

/* ------------------------------------------------------------------ ZMTP 3.0 over TCP (RFC 23): a DEALER */

static double now_s(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

/* wait until the socket is ready for `events` or the deadline passes: 1 ready, 0 timeout, -1 error */
static int wait_fd(int fd, short events, double deadline) {
    for (;;) {
        double left = deadline - now_s();
        if (left <= 0) return 0;
        struct pollfd p = {fd, events, 0};
        int r = poll(&p, 1, (int)(left * 1000) + 1);
        if (r > 0) return (p.revents & (POLLERR | POLLNVAL)) && !(p.revents & events) ? -1 : 1;
        if (r == 0) continue;
        if (errno != EINTR) return -1;
    }
}

static int send_all(hl_fmu *f, const void *data, size_t n, double deadline) {
    const unsigned char *p = data;
    while (n) {
        if (wait_fd(f->sock, POLLOUT, deadline) != 1) return -1;
        ssize_t w = send(f->sock, p, n, MSG_NOSIGNAL);
        if (w < 0 && (errno == EAGAIN || errno == EINTR)) continue;
        if (w <= 0) return -1;
        p += w;
        n -= (size_t)w;
    }
    return 0;
}

static int recv_all(hl_fmu *f, void *data, size_t n, double deadline) {
    unsigned char *p = data;
    while (n) {
        int ready = wait_fd(f->sock, POLLIN, deadline);
        if (ready == 0) return -2;     /* timeout */
        if (ready < 0) return -1;
        ssize_t r = recv(f->sock, p, n, 0);
        if (r < 0 && (errno == EAGAIN || errno == EINTR)) continue;
        if (r <= 0) return -1;         /* closed by the server */
        p += r;
        n -= (size_t)r;
    }
    return 0;
}

static int send_frame(hl_fmu *f, unsigned char flags, const void *data, size_t n, double deadline) {
    unsigned char h[9];
    size_t hn;
    if (n <= 255) { h[0] = flags; h[1] = (unsigned char)n; hn = 2; }
    else { h[0] = flags | 0x02; for (int i = 0; i < 8; i++) h[1 + i] = (unsigned char)((uint64_t)n >> (56 - 8 * i)); hn = 9; }
    if (send_all(f, h, hn, deadline)) return -1;
    return send_all(f, data, n, deadline);
}

/* one frame: flags and body (malloc'ed) */
static int recv_frame(hl_fmu *f, unsigned char *flags, unsigned char **body, size_t *n, double deadline) {
    unsigned char h[8];
    int r = recv_all(f, flags, 1, deadline);
    if (r) return r;
    if (*flags & 0x02) {
        if ((r = recv_all(f, h, 8, deadline))) return r;
        uint64_t len = 0;
        for (int i = 0; i < 8; i++) len = len << 8 | h[i];
        if (len > ((uint64_t)1 << 31)) return -1;
        *n = (size_t)len;
    } else {
        if ((r = recv_all(f, h, 1, deadline))) return r;
        *n = h[0];
    }
    *body = malloc(*n ? *n : 1);
    if (!*body) return -1;
    if ((r = recv_all(f, *body, *n, deadline))) { free(*body); *body = NULL; return r; }
    return 0;
}

static int connect_server(hl_fmu *f, double deadline) {
    char host[512], port[32];
    const char *a = f->server;
    if (strncmp(a, "tcp://", 6) || !strrchr(a + 6, ':')) {
        hl_log(f, 1, "server_address %s: expected tcp://HOST:PORT (the native FMU speaks TCP)", a);
        return -1;
    }
    const char *colon = strrchr(a + 6, ':');
    size_t hl = (size_t)(colon - (a + 6));
    if (hl >= sizeof host) hl = sizeof host - 1;
    memcpy(host, a + 6, hl);
    host[hl] = 0;
    if (host[0] == '[' && hl > 1 && host[hl - 1] == ']') { memmove(host, host + 1, hl - 2); host[hl - 2] = 0; }
    snprintf(port, sizeof port, "%s", colon + 1);
    struct addrinfo hints = {0}, *res = NULL;
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    int gai = getaddrinfo(host, port, &hints, &res);
    if (gai) { hl_log(f, 1, "server_address %s: %s", a, gai_strerror(gai)); return -1; }
    int err = ECONNREFUSED;
    while (now_s() < deadline) {   /* a server that is starting: retry until the timeout */
        for (struct addrinfo *ai = res; ai; ai = ai->ai_next) {
            int s = socket(ai->ai_family, ai->ai_socktype, ai->ai_protocol);
            if (s < 0) { err = errno; continue; }
            fcntl(s, F_SETFL, fcntl(s, F_GETFL) | O_NONBLOCK);
            int one = 1;
            setsockopt(s, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
            if (connect(s, ai->ai_addr, ai->ai_addrlen) == 0 || errno == EINPROGRESS) {
                f->sock = s;
                int ready = wait_fd(s, POLLOUT, deadline);
                socklen_t len = sizeof err;
                if (ready == 1 && getsockopt(s, SOL_SOCKET, SO_ERROR, &err, &len) == 0 && err == 0) {
                    freeaddrinfo(res);
                    return 0;
                }
                if (ready == 0) err = ETIMEDOUT;
            } else {
                err = errno;
            }
            close(s);
            f->sock = -1;
        }
        struct timespec ts = {0, 200000000};
        nanosleep(&ts, NULL);
    }
    freeaddrinfo(res);
    hl_log(f, 1, "no hydrolink server answered at %s within %g s (%s): start one there (hydrolink serve --bind "
                 "tcp://0.0.0.0:PORT) or set the FMU's server_address parameter", a, f->timeout, strerror(err));
    return -1;
}

/* TCP connection and the ZMTP 3.0 handshake (NULL mechanism, socket type DEALER) */
static int open_link(hl_fmu *f) {
    double deadline = now_s() + f->timeout;
    if (connect_server(f, deadline)) return -1;
    unsigned char greeting[64] = {0xff, 0, 0, 0, 0, 0, 0, 0, 1, 0x7f, 3, 0};
    memcpy(greeting + 12, "NULL", 4);
    unsigned char peer[64];
    static const unsigned char ready[] = "\x05READY\x0bSocket-Type\x00\x00\x00\x06" "DEALER";
    if (send_all(f, greeting, 64, deadline) || recv_all(f, peer, 64, deadline)) goto broken;
    if (peer[0] != 0xff || peer[9] != 0x7f || peer[10] < 3 || memcmp(peer + 12, "NULL", 5)) {
        hl_log(f, 1, "%s is not a hydrolink server without CURVE (its ZeroMQ greeting asks for another mechanism "
                     "or version; the native FMU speaks ZMTP 3 with the NULL mechanism)", f->server);
        close_socket(f);
        return -1;
    }
    if (send_frame(f, 0x04, ready, sizeof ready - 1, deadline)) goto broken;
    unsigned char flags, *body = NULL;
    size_t n;
    if (recv_frame(f, &flags, &body, &n, deadline)) goto broken;
    int ok = (flags & 0x04) && n >= 6 && !memcmp(body, "\x05READY", 6);
    free(body);
    if (!ok) goto broken;
    return 0;
broken:
    hl_log(f, 1, "the ZeroMQ handshake with %s failed (is it a hydrolink server?)", f->server);
    close_socket(f);
    return -1;
}

/* ------------------------------------------------------------------ requests (SPEC §3, §6) */

typedef struct { unsigned char *frame; rd_t rd; node_t root; } reply_t;

static void reply_free(reply_t *r) {
    free(r->frame);
    free(r->rd.pool);
    memset(r, 0, sizeof *r);
}

static void begin(hl_fmu *f, buf_t *b, const char *type, int extra) {
    b->n = 0;
    snprintf(f->msg_id, sizeof f->msg_id, "fmu-%ld", ++f->next_id);
    mp_map(b, 4 + (size_t)extra);
    mp_str(b, "v"); mp_int(b, 1);
    mp_str(b, "type"); mp_str(b, type);
    mp_str(b, "msg_id"); mp_str(b, f->msg_id);
    mp_str(b, "session");
    if (f->session[0]) mp_str(b, f->session); else mp_nil(b);
}

/* send the request in b and read its reply (the one whose parent is its msg_id); a lost
 * connection is opened again and the request sent again once (§5.3 answers a repeated step from
 * its cache). An `error` reply is logged and returns -1 unless `code_ok` names its code. */
static int request(hl_fmu *f, buf_t *b, reply_t *out, long code_ok) {
    memset(out, 0, sizeof *out);
    if (b->oom) { hl_log(f, 1, "out of memory building a request"); return -1; }
    for (int attempt = 0; attempt < (f->closing ? 1 : 2); attempt++) {
        if (f->sock < 0 && open_link(f)) return -1;
        double deadline = now_s() + f->timeout;
        int lost = send_frame(f, 0x00, b->p, b->n, deadline) != 0;
        while (!lost) {
            unsigned char flags, *body = NULL;
            size_t n;
            int r = recv_frame(f, &flags, &body, &n, deadline);
            if (r == -2) {
                hl_log(f, 1, "no reply from the hydrolink server at %s within %g s (timeout parameter)", f->server, f->timeout);
                close_socket(f);
                return -1;
            }
            if (r) { lost = 1; break; }
            if (flags & 0x04) {                        /* a command: answer PING with PONG (ZMTP 3.1) */
                if (n >= 5 && !memcmp(body, "\x04PING", 5)) {
                    buf_t pong = {0};
                    put(&pong, "\x04PONG", 5);
                    if (n > 7) put(&pong, body + 7, n - 7);
                    if (!pong.oom) lost = send_frame(f, 0x04, pong.p, pong.n, deadline) != 0;
                    free(pong.p);
                }
                free(body);
                continue;
            }
            out->frame = body;
            out->rd.p = body;
            out->rd.end = body + n;
            out->rd.cap = n + 1;
            out->rd.pool = calloc(out->rd.cap, sizeof(node_t));
            if (!out->rd.pool) { reply_free(out); hl_log(f, 1, "out of memory reading a reply"); return -1; }
            parse(&out->rd, &out->root, 0);
            if (out->rd.bad || out->root.type != T_MAP) { reply_free(out); continue; }   /* not for us: skip */
            if (!is_str(get(&out->root, "parent"), f->msg_id)) { reply_free(out); continue; }   /* a late reply */
            if (is_str(get(&out->root, "type"), "error")) {
                double code = 99;
                num(get(&out->root, "code"), &code);
                if ((long)code == code_ok) return 0;
                const node_t *m = get(&out->root, "message"), *fld = get(&out->root, "field");
                hl_log(f, 1, "the hydrolink server at %s answered error %.0f [%.*s]: %.*s", f->server, code,
                       fld && fld->type == T_STR ? (int)fld->n : 0, fld && fld->type == T_STR ? (const char *)fld->p : "",
                       m && m->type == T_STR ? (int)m->n : 0, m && m->type == T_STR ? (const char *)m->p : "");
                reply_free(out);
                return -1;
            }
            return 0;
        }
        close_socket(f);                               /* the connection was lost: once more */
    }
    if (!f->closing) hl_log(f, 1, "lost the connection to the hydrolink server at %s", f->server);
    return -1;
}

/* ------------------------------------------------------------------ the session */

static void pack_hello(hl_fmu *f, buf_t *b) {
    begin(f, b, "hello", 4);
    mp_str(b, "role"); mp_str(b, "multibody");
    mp_str(b, "scene"); mp_str(b, f->scene);
    mp_str(b, "hdbs");
    mp_map(b, (size_t)f->n_hdb);
    for (int i = 0; i < f->n_hdb; i++) {
        hdb_t *h = &f->hdb[i];
        mp_str(b, h->key);
        mp_map(b, 2);
        mp_str(b, "format"); mp_str(b, h->format ? h->format : "");
        mp_str(b, "files");
        mp_map(b, (size_t)h->n_files);
        for (int k = 0; k < h->n_files; k++) { mp_str(b, h->names[k]); mp_str(b, h->hash[k]); }
    }
    mp_str(b, "client");
    mp_map(b, 2);
    mp_str(b, "name"); mp_str(b, "hydrolink-native-fmu");
    mp_str(b, "version"); mp_str(b, "1");
}

static int upload(hl_fmu *f, const node_t *missing) {
    if (!missing || missing->type != T_ARR) { hl_log(f, 1, "error 13 without the missing hashes"); return -1; }
    char want[MAX_HDB * MAX_FILES][65];
    uint32_t n = missing->n < MAX_HDB * MAX_FILES ? missing->n : MAX_HDB * MAX_FILES;
    for (uint32_t j = 0; j < n; j++) {                 /* copied: the next request frees the reply */
        const node_t *h = &missing->kids[j];
        if (h->type != T_STR || h->n != 64) { hl_log(f, 1, "error 13 lists a malformed hash"); return -1; }
        memcpy(want[j], h->p, 64);
        want[j][64] = 0;
    }
    for (uint32_t j = 0; j < n; j++) {
        const hdb_t *h = NULL;
        int k = -1;
        for (int i = 0; i < f->n_hdb && k < 0; i++)
            for (int m = 0; m < f->hdb[i].n_files; m++)
                if (!strcmp(f->hdb[i].hash[m], want[j])) { h = &f->hdb[i]; k = m; break; }
        if (k < 0) { hl_log(f, 1, "the server asked for content %s, which is none of the FMU's HDB files", want[j]); return -1; }
        buf_t b = {0};
        begin(f, &b, "upload", 2);
        mp_str(&b, "sha256"); mp_str(&b, h->hash[k]);
        mp_str(&b, "data"); mp_bin(&b, h->data[k], h->size[k]);
        reply_t r;
        int rc = request(f, &b, &r, -1);
        free(b.p);
        if (rc) return -1;
        reply_free(&r);
        hl_log(f, 0, "uploaded %s (%zu bytes) to the server's HDB store", h->names[k], h->size[k]);
    }
    return 0;
}

/* SPEC §5.1: a client shows every setup warning to its user before the run: the importer's logger,
 * status warning (a warning that is not a string is a malformed welcome: said so, not skipped) */
static void log_setup_warnings(hl_fmu *f, const node_t *warnings) {
    if (!warnings || warnings->type != T_ARR) {
        hl_log(f, HL_WARNING, "the server's welcome has no setup.warnings list: its warnings cannot be shown");
        return;
    }
    for (uint32_t k = 0; k < warnings->n; k++) {
        const node_t *w = &warnings->kids[k];
        if (w->type == T_STR) hl_log(f, HL_WARNING, "hydrolink server: %.*s", (int)w->n, (const char *)w->p);
        else hl_log(f, HL_WARNING, "the server's setup.warnings[%u] is not a string", (unsigned)k);
    }
}

int hl_start(hl_fmu *f) {
    if (f->failed) return -1;
    if (!f->server[0]) {
        hl_log(f, 1, "the parameter server_address is empty: the native FMU needs a running hydrolink server "
                     "(hydrolink serve --bind tcp://0.0.0.0:PORT), e.g. server_address = tcp://127.0.0.1:5555");
        return -1;
    }
    f->session[0] = 0;
    buf_t b = {0};
    reply_t r;
    pack_hello(f, &b);
    int rc = request(f, &b, &r, 13);
    if (!rc && is_str(get(&r.root, "type"), "error")) {   /* 13 missing_content: upload, hello again */
        rc = upload(f, get(&r.root, "missing"));
        reply_free(&r);
        if (!rc) { pack_hello(f, &b); rc = request(f, &b, &r, -1); }
    }
    free(b.p);
    if (rc) return -1;
    const node_t *sid = get(&r.root, "session"), *setup = get(&r.root, "setup");
    double dt = 0;
    if (!sid || sid->type != T_STR || sid->n >= sizeof f->session || !num(get(setup, "dt"), &dt)) {
        hl_log(f, 1, "the server's welcome has no session or setup.dt");
        reply_free(&r);
        return -1;
    }
    memcpy(f->session, sid->p, sid->n);
    f->session[sid->n] = 0;
    log_setup_warnings(f, get(setup, "warnings"));
    reply_free(&r);
    if (fabs(dt - f->dt) > 1e-12 * f->dt) {
        hl_log(f, 1, "the server's dt %g differs from the exported %g (export the FMU again)", dt, f->dt);
        return -1;
    }
    f->clk.seq = 0;
    f->clk.iteration = -1;
    f->clk.evaluated = 0;
    hl_log(f, 0, "session %s on %s", f->session, f->server);
    return 0;
}

/* the server's forces for the current inputs at the current step (a new iteration if they changed) */
static int evaluate(hl_fmu *f) {
    if (f->failed) return -1;
    if (!f->session[0]) { hl_log(f, 1, "outputs need a session: exit initialization mode first"); return -1; }
    int na = f->na, nb = f->n_bodies;
    if (f->clk.evaluated && !memcmp(f->sent, f->x, na * sizeof(double)) && !memcmp(f->sent + na, f->v, na * sizeof(double)))
        return 0;
    memcpy(f->pos6, f->equilibrium, (size_t)(6 * nb) * sizeof(double));
    memset(f->vel6, 0, (size_t)(6 * nb) * sizeof(double));
    for (int i = 0; i < na; i++) { f->pos6[f->flat[i]] += f->x[i]; f->vel6[f->flat[i]] = f->v[i]; }
    buf_t b = {0};
    begin(f, &b, "step", 5);
    mp_str(&b, "seq"); mp_int(&b, f->clk.seq);
    mp_str(&b, "time"); mp_f64(&b, f->clk.seq * f->dt);
    mp_str(&b, "iteration"); mp_int(&b, f->clk.iteration + 1);
    mp_str(&b, "position"); mp_rows6(&b, f->pos6, nb);
    mp_str(&b, "velocity"); mp_rows6(&b, f->vel6, nb);
    reply_t r;
    int rc = request(f, &b, &r, -1);
    free(b.p);
    if (rc) { f->failed = 1; return -1; }
    double *part = malloc((size_t)(6 * nb) * sizeof(double)), *extra = calloc((size_t)(6 * nb), sizeof(double));
    const char *names[3] = {"excitation", "radiation", "hydrostatic"};
    int ok = part && extra && num(get(&r.root, "wave_elevation"), &f->eta);
    for (int k = 0; ok && k < 3; k++) {
        ok = f8(get(&r.root, names[k]), part, (size_t)(6 * nb));
        for (int i = 0; ok && i < na; i++) f->out[(1 + k) * na + i] = part[f->flat[i]];
    }
    const char *more[2] = {"viscous", "morison"};   /* scenes with those terms: part of the force */
    for (int k = 0; ok && k < 2; k++) {
        const node_t *o = get(&r.root, more[k]);
        if (o && o->type != T_NIL) {
            ok = f8(o, part, (size_t)(6 * nb));
            for (int i = 0; ok && i < (6 * nb); i++) extra[i] += part[i];
        }
    }
    if (ok) {
        for (int i = 0; i < na; i++) {
            f->out[3 * na + i] += f->net_buoyancy[i];
            f->out[4 * na + i] = f->out[na + i] + f->out[2 * na + i] + extra[f->flat[i]];
            f->out[i] = f->out[4 * na + i] + f->out[3 * na + i];
        }
        memcpy(f->sent, f->x, na * sizeof(double));
        memcpy(f->sent + na, f->v, na * sizeof(double));
        f->clk.iteration++;
        f->clk.evaluated = 1;
    } else {
        hl_log(f, 1, "a forces reply without its arrays (excitation, radiation, hydrostatic (%d, 6), wave_elevation)", nb);
        f->failed = 1;
    }
    free(part);
    free(extra);
    reply_free(&r);
    return ok ? 0 : -1;
}

int hl_do_step(hl_fmu *f, double time, double step) {
    if (f->failed) return -1;
    if (fabs(step - f->dt) > 1e-9 * f->dt) {
        hl_log(f, 1, "communication step %.17g s at t = %g: this FMU takes only its scene's dt = %.17g s "
                     "(set the master's step to it)", step, time, f->dt);
        return -1;
    }
    if (fabs(time - f->clk.seq * f->dt) > 1e-6 * f->dt + 1e-12 * fabs(time)) {
        hl_log(f, 1, "doStep at t = %.17g, but this FMU is at t = %.17g (restore a state to go back)", time, f->clk.seq * f->dt);
        return -1;
    }
    if (evaluate(f)) return -1;     /* every step gets its sample, even if no output was read */
    f->clk.seq++;
    f->clk.iteration = -1;
    f->clk.evaluated = 0;
    return 0;
}

static int set_real(hl_fmu *f, unsigned vr, double value) {
    if (vr == HL_VR_TIMEOUT) {
        if (!(value > 0)) { hl_log(f, 1, "timeout must be > 0 s, got %g", value); return -1; }
        f->timeout = value;
        return 0;
    }
    if (vr >= HL_VR_DOF && vr < HL_VR_DOF + 8u * (unsigned)f->na && (vr - HL_VR_DOF) % 8 < 2) {
        unsigned i = (vr - HL_VR_DOF) / 8, k = (vr - HL_VR_DOF) % 8;
        (k ? f->v : f->x)[i] = value;
        return 0;
    }
    hl_log(f, 1, "value reference %u is not a settable real of this FMU", vr);
    return -1;
}

static int get_real(hl_fmu *f, unsigned vr, double *value) {
    int na = f->na;
    if (vr == HL_VR_TIMEOUT) { *value = f->timeout; return 0; }
    if (vr == HL_VR_TIME) { *value = f->clk.seq * f->dt; return 0; }
    if (vr >= HL_VR_AINF && vr < HL_VR_AINF + (unsigned)(na * na)) { *value = f->a_inf[vr - HL_VR_AINF]; return 0; }
    if (vr >= HL_VR_KHS && vr < HL_VR_KHS + (unsigned)(na * na)) { *value = f->k_hs[vr - HL_VR_KHS]; return 0; }
    if (vr >= HL_VR_DOF && vr < HL_VR_DOF + 8u * (unsigned)na) {
        unsigned i = (vr - HL_VR_DOF) / 8, k = (vr - HL_VR_DOF) % 8;
        if (k < 2) { *value = (k ? f->v : f->x)[i]; return 0; }
        if (k == 7) { *value = f->net_buoyancy[i]; return 0; }
        if (!f->session[0]) { *value = 0.0; return 0; }   /* before initialization: the start value */
        if (evaluate(f)) return -1;
        *value = f->out[(k - 2) * na + i];
        return 0;
    }
    if (vr == HL_VR_ETA) {
        if (!f->session[0]) { *value = 0.0; return 0; }
        if (evaluate(f)) return -1;
        *value = f->eta;
        return 0;
    }
    hl_log(f, 1, "value reference %u is not a real of this FMU", vr);
    return -1;
}

static int set_string(hl_fmu *f, unsigned vr, const char *value) {
    if (vr != HL_VR_SERVER) { hl_log(f, 1, "value reference %u is not a string parameter", vr); return -1; }
    if (f->session[0]) { hl_log(f, 1, "server_address is fixed once the session is open"); return -1; }
    if (strlen(value ? value : "") >= sizeof f->server) { hl_log(f, 1, "server_address is too long"); return -1; }
    snprintf(f->server, sizeof f->server, "%s", value ? value : "");
    return 0;
}

static int get_string(hl_fmu *f, unsigned vr, const char **value) {
    if (vr != HL_VR_SERVER) { hl_log(f, 1, "value reference %u is not a string parameter", vr); return -1; }
    *value = f->server;
    return 0;
}

/* the FMI getters and setters: one value reference after the other, stopping at the first error */
int hl_set_reals(hl_fmu *f, const unsigned vr[], size_t n, const double value[]) {
    for (size_t k = 0; k < n; k++)
        if (set_real(f, vr[k], value[k])) return -1;
    return 0;
}

int hl_get_reals(hl_fmu *f, const unsigned vr[], size_t n, double value[]) {
    for (size_t k = 0; k < n; k++)
        if (get_real(f, vr[k], &value[k])) return -1;
    return 0;
}

int hl_set_strings(hl_fmu *f, const unsigned vr[], size_t n, const char *const value[]) {
    for (size_t k = 0; k < n; k++)
        if (set_string(f, vr[k], value[k])) return -1;
    return 0;
}

int hl_get_strings(hl_fmu *f, const unsigned vr[], size_t n, const char *value[]) {
    for (size_t k = 0; k < n; k++)
        if (get_string(f, vr[k], &value[k])) return -1;
    return 0;
}

/* ------------------------------------------------------------------ states (SPEC §5.9) */

typedef struct { long server_state; clock_t_ clk; double vals[]; } state_t;   /* vals: x, v, sent, out (5 na), eta */

int hl_get_state(hl_fmu *f, void **state) {
    if (f->failed) return -1;
    int na = f->na;
    state_t *s = malloc(sizeof *s + (size_t)(9 * na + 1) * sizeof(double));
    if (!s) { hl_log(f, 1, "out of memory saving the FMU state"); return -1; }
    s->server_state = 0;
    if (f->session[0]) {
        buf_t b = {0};
        reply_t r;
        begin(f, &b, "save", 0);
        int rc = request(f, &b, &r, -1);
        free(b.p);
        double id = 0;
        if (rc || !num(get(&r.root, "state"), &id)) { free(s); if (!rc) reply_free(&r); return -1; }
        reply_free(&r);
        s->server_state = (long)id;
    }
    s->clk = f->clk;
    memcpy(s->vals, f->x, na * sizeof(double));
    memcpy(s->vals + na, f->v, na * sizeof(double));
    memcpy(s->vals + 2 * na, f->sent, 2 * na * sizeof(double));
    memcpy(s->vals + 4 * na, f->out, 5 * na * sizeof(double));
    s->vals[9 * na] = f->eta;
    *state = s;
    return 0;
}

int hl_set_state(hl_fmu *f, const void *state) {
    const state_t *s = state;
    int na = f->na;
    if (!s) { hl_log(f, 1, "no FMU state given"); return -1; }
    if (s->server_state) {
        if (!f->session[0]) { hl_log(f, 1, "this state belongs to a session: the FMU has none now"); return -1; }
        buf_t b = {0};
        reply_t r;
        begin(f, &b, "restore", 1);
        mp_str(&b, "state"); mp_int(&b, s->server_state);
        int rc = request(f, &b, &r, -1);
        free(b.p);
        if (rc) return -1;
        reply_free(&r);
    }
    f->failed = 0;
    f->clk = s->clk;
    memcpy(f->x, s->vals, na * sizeof(double));
    memcpy(f->v, s->vals + na, na * sizeof(double));
    memcpy(f->sent, s->vals + 2 * na, 2 * na * sizeof(double));
    memcpy(f->out, s->vals + 4 * na, 5 * na * sizeof(double));
    f->eta = s->vals[9 * na];
    return 0;
}

void hl_free_state(hl_fmu *f, void *state) {
    state_t *s = state;
    if (!s) return;
    if (s->server_state && f->session[0] && f->sock >= 0) {
        buf_t b = {0};
        reply_t r;
        begin(f, &b, "release", 1);
        mp_str(&b, "state"); mp_int(&b, s->server_state);
        if (!request(f, &b, &r, -1)) reply_free(&r);
        free(b.p);
    }
    free(s);
}

void hl_terminate(hl_fmu *f) {
    if (f->session[0] && f->sock >= 0) {
        buf_t b = {0};
        reply_t r;
        double keep = f->timeout;
        f->timeout = keep < 2.0 ? keep : 2.0;
        f->closing = 1;
        begin(f, &b, "bye", 0);
        if (!request(f, &b, &r, -1)) reply_free(&r);
        free(b.p);
        f->timeout = keep;
        f->closing = 0;
    }
    f->session[0] = 0;
    close_socket(f);
}
