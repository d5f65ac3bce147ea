/*
 * A stand-in for FANUC's libfwlib32.so: the subset compd uses, with the real
 * ABI (cdecl, every FOCAS "long" 32 bits, structs packed to 4).
 *
 * The "controller" is a shared-memory file written by the simulator process
 * (drivers/sim/focas_server.py) and read here:
 *   $COMPD_FOCAS_SIM_DIR (default /tmp/compd-focas-sim) / <ip>-<port>.shm
 * A missing file or online == 0 is a pulled cable (EW_SOCKET); a generation
 * different from the one a handle was opened under is a power cycle (the
 * handle is stale: EW_HANDLE). latency_us delays every call. busy_writes > 0
 * makes the next pmc_wrpmcrng calls answer EW_BUSY (a transient refusal: the
 * CNC is busy), one per call, counting down.
 *
 * Build: gcc -shared -fPIC -O2 -o libfwlib32.so fwlib_standin.c
 * ABI probe: gcc -DCOMPD_ABI_PROBE -o probe fwlib_standin.c && ./probe
 */
#include <errno.h>
#include <fcntl.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

typedef int32_t FLONG; /* FOCAS "long": 32 bits on every platform */

#define EW_OK 0
#define EW_BUSY (-1)
#define EW_LENGTH 2
#define EW_NUMBER 3
#define EW_ATTRIB 4
#define EW_PROT 7
#define EW_HANDLE (-8)
#define EW_SOCKET (-16)

#define MAX_AXIS 32
#define MAX_SPINDLE 8

#pragma pack(push, 4)
typedef struct iodbpmc {
    short type_a;
    short type_d;
    unsigned short datano_s;
    unsigned short datano_e;
    union {
        char cdata[5];
        short idata[5];
        FLONG ldata[5];
        float fdata[5];
        double dbdata[5];
    } u;
} IODBPMC;

typedef struct odbspn {
    short datano;
    short type;
    short data[MAX_SPINDLE];
} ODBSPN;

typedef struct realdgn {
    FLONG dgn_val;
    FLONG dec_val;
} REALDGN;

typedef struct odbdgn {
    short datano;
    short type;
    union {
        char cdata;
        short idata;
        FLONG ldata;
        REALDGN rdata;
        char cdatas[MAX_AXIS];
        short idatas[MAX_AXIS];
        FLONG ldatas[MAX_AXIS];
        REALDGN rdatas[MAX_AXIS];
    } u;
} ODBDGN;
#pragma pack(pop)

/* ---- shared memory layout (mirrored in drivers/sim/focas_server.py) ---- */
#define SIM_MAGIC 0x53434f46u /* "FOCS" */
#define SIM_PMC_AREAS 14
#define SIM_PMC_BYTES 8192
#define SIM_DIAGS 32

typedef struct sim_diag {
    int32_t number;
    int32_t axis;
    int32_t value;
} sim_diag;

typedef struct sim_shm {
    uint32_t magic;      /* 0 */
    uint32_t online;     /* 4 */
    uint32_t generation; /* 8 */
    uint32_t latency_us; /* 12 */
    uint32_t calls;      /* 16: data calls served */
    uint32_t n_diag;     /* 20 */
    int32_t spload[MAX_SPINDLE];  /* 24 */
    sim_diag diag[SIM_DIAGS];     /* 56 */
    uint8_t pmc[SIM_PMC_AREAS][SIM_PMC_BYTES]; /* 440 */
    uint32_t busy_writes; /* 115128: the next this many pmc_wrpmcrng get EW_BUSY */
} sim_shm;

#ifdef COMPD_ABI_PROBE
int main(void) {
    printf("IODBPMC %zu %zu %zu %zu %zu\n", sizeof(IODBPMC), offsetof(IODBPMC, type_d),
           offsetof(IODBPMC, datano_s), offsetof(IODBPMC, datano_e), offsetof(IODBPMC, u));
    printf("ODBSPN %zu %zu %zu\n", sizeof(ODBSPN), offsetof(ODBSPN, type),
           offsetof(ODBSPN, data));
    printf("ODBDGN %zu %zu %zu\n", sizeof(ODBDGN), offsetof(ODBDGN, type), offsetof(ODBDGN, u));
    printf("REALDGN %zu %zu\n", sizeof(REALDGN), offsetof(REALDGN, dec_val));
    printf("SHM %zu %zu %zu %zu %zu\n", sizeof(sim_shm), offsetof(sim_shm, spload),
           offsetof(sim_shm, diag), offsetof(sim_shm, pmc), offsetof(sim_shm, busy_writes));
    return 0;
}
#else

#define MAX_HANDLES 64

typedef struct slot {
    int in_use;
    uint32_t generation;
    sim_shm *shm;
} slot;

static slot slots[MAX_HANDLES];

static void delay(const sim_shm *shm) {
    uint32_t us = shm->latency_us;
    if (us) {
        struct timespec ts = {us / 1000000u, (long)(us % 1000000u) * 1000L};
        while (nanosleep(&ts, &ts) == -1 && errno == EINTR) {
        }
    }
}

/* Validate a handle; on success *out is the controller's memory. */
static short enter(unsigned short h, sim_shm **out) {
    if (h == 0 || h > MAX_HANDLES || !slots[h - 1].in_use) return EW_HANDLE;
    sim_shm *shm = slots[h - 1].shm;
    if (!shm->online) return EW_SOCKET;
    if (shm->generation != slots[h - 1].generation) return EW_HANDLE;
    delay(shm);
    __atomic_add_fetch(&shm->calls, 1, __ATOMIC_RELAXED);
    *out = shm;
    return EW_OK;
}

short cnc_startupprocess(FLONG level, const char *filename) {
    (void)level;
    (void)filename;
    return EW_OK;
}

short cnc_exitprocess(void) { return EW_OK; }

short cnc_allclibhndl3(const char *ip, unsigned short port, FLONG timeout,
                       unsigned short *FlibHndl) {
    (void)timeout;
    char path[512];
    const char *dir = getenv("COMPD_FOCAS_SIM_DIR");
    if (!dir || !*dir) dir = "/tmp/compd-focas-sim";
    if (!ip || !FlibHndl) return EW_SOCKET;
    snprintf(path, sizeof path, "%s/%s-%u.shm", dir, ip, (unsigned)port);
    int fd = open(path, O_RDWR);
    if (fd < 0) return EW_SOCKET;
    void *p = mmap(NULL, sizeof(sim_shm), PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
    close(fd);
    if (p == MAP_FAILED) return EW_SOCKET;
    sim_shm *shm = (sim_shm *)p;
    if (shm->magic != SIM_MAGIC || !shm->online) {
        munmap(p, sizeof(sim_shm));
        return EW_SOCKET;
    }
    delay(shm);
    for (int i = 0; i < MAX_HANDLES; i++) {
        if (!slots[i].in_use) {
            slots[i].in_use = 1;
            slots[i].generation = shm->generation;
            slots[i].shm = shm;
            *FlibHndl = (unsigned short)(i + 1);
            return EW_OK;
        }
    }
    munmap(p, sizeof(sim_shm));
    return EW_HANDLE;
}

short cnc_freelibhndl(unsigned short FlibHndl) {
    if (FlibHndl == 0 || FlibHndl > MAX_HANDLES || !slots[FlibHndl - 1].in_use) return EW_HANDLE;
    munmap(slots[FlibHndl - 1].shm, sizeof(sim_shm));
    slots[FlibHndl - 1].in_use = 0;
    slots[FlibHndl - 1].shm = NULL;
    return EW_OK;
}

static int type_size(short data_type) {
    switch (data_type) {
        case 0: return 1;
        case 1: return 2;
        case 2: return 4;
        case 4: return 4;
        case 5: return 8;
        default: return 0;
    }
}

static short check_range(short adr_type, short data_type, unsigned short s, unsigned short e,
                         unsigned short length) {
    int size = type_size(data_type);
    if (adr_type < 0 || adr_type >= SIM_PMC_AREAS || size == 0) return EW_ATTRIB;
    if (e < s || e >= SIM_PMC_BYTES) return EW_NUMBER;
    int n = (int)e - (int)s + 1;
    if (n % size != 0 || length != 8 + n) return EW_LENGTH;
    return EW_OK;
}

short pmc_rdpmcrng(unsigned short FlibHndl, short adr_type, short data_type,
                   unsigned short s_number, unsigned short e_number, unsigned short length,
                   IODBPMC *buf) {
    sim_shm *shm;
    short rc = enter(FlibHndl, &shm);
    if (rc != EW_OK) return rc;
    rc = check_range(adr_type, data_type, s_number, e_number, length);
    if (rc != EW_OK) return rc;
    buf->type_a = adr_type;
    buf->type_d = data_type;
    buf->datano_s = s_number;
    buf->datano_e = e_number;
    memcpy((char *)buf + 8, &shm->pmc[adr_type][s_number], (size_t)(e_number - s_number + 1));
    return EW_OK;
}

/* Take one from busy_writes if it is above 0 (the simulator may set it meanwhile). */
static int take_busy(sim_shm *shm) {
    uint32_t n = __atomic_load_n(&shm->busy_writes, __ATOMIC_RELAXED);
    while (n > 0) {
        if (__atomic_compare_exchange_n(&shm->busy_writes, &n, n - 1, 0, __ATOMIC_RELAXED,
                                        __ATOMIC_RELAXED))
            return 1;
    }
    return 0;
}

short pmc_wrpmcrng(unsigned short FlibHndl, unsigned short length, IODBPMC *buf) {
    sim_shm *shm;
    short rc = enter(FlibHndl, &shm);
    if (rc != EW_OK) return rc;
    if (take_busy(shm)) return EW_BUSY;
    rc = check_range(buf->type_a, buf->type_d, buf->datano_s, buf->datano_e, length);
    if (rc != EW_OK) return rc;
    if (buf->type_a == 1 || buf->type_a == 3) return EW_PROT; /* F, X: CNC/machine inputs */
    memcpy(&shm->pmc[buf->type_a][buf->datano_s], (char *)buf + 8,
           (size_t)(buf->datano_e - buf->datano_s + 1));
    return EW_OK;
}

short cnc_rdspload(unsigned short FlibHndl, short sp_no, ODBSPN *serialspindle) {
    sim_shm *shm;
    short rc = enter(FlibHndl, &shm);
    if (rc != EW_OK) return rc;
    memset(serialspindle, 0, sizeof *serialspindle);
    if (sp_no == -1) {
        serialspindle->datano = -1;
        for (int i = 0; i < MAX_SPINDLE; i++) serialspindle->data[i] = (short)shm->spload[i];
        return EW_OK;
    }
    if (sp_no < 1 || sp_no > MAX_SPINDLE) return EW_NUMBER;
    serialspindle->datano = sp_no;
    serialspindle->data[0] = (short)shm->spload[sp_no - 1];
    return EW_OK;
}

/* Every simulated diagnosis is long-typed: length must be 4 + 4. */
short cnc_diagnoss(unsigned short FlibHndl, short number, short axis, short length,
                   ODBDGN *diagnoss) {
    sim_shm *shm;
    short rc = enter(FlibHndl, &shm);
    if (rc != EW_OK) return rc;
    if (length != 4 + (short)sizeof(FLONG)) return EW_LENGTH;
    uint32_t n = shm->n_diag < SIM_DIAGS ? shm->n_diag : SIM_DIAGS;
    int number_known = 0;
    for (uint32_t i = 0; i < n; i++) {
        if (shm->diag[i].number != number) continue;
        number_known = 1;
        if (shm->diag[i].axis == axis) {
            diagnoss->datano = number;
            diagnoss->type = axis;
            diagnoss->u.ldata = shm->diag[i].value;
            return EW_OK;
        }
    }
    return number_known ? EW_ATTRIB : EW_NUMBER;
}
#endif
