/* seccomp_exec: run a command under the system call filter a systemd unit
 * would install, so the tests can check that compd still works inside it
 * without a running systemd.
 *
 *   seccomp_exec ALLOWED_FILE [--mdwx] -- COMMAND [ARGS...]
 *
 * ALLOWED_FILE lists one allowed system call name per line (the expanded
 * SystemCallFilter= set); every other call fails with EPERM, as with
 * SystemCallErrorNumber=EPERM. --mdwx adds MemoryDenyWriteExecute=yes's
 * rules: mmap with PROT_WRITE|PROT_EXEC, and mprotect/pkey_mprotect adding
 * PROT_EXEC, fail with EPERM. Names unknown on this architecture are skipped.
 * Exit 125 when the filter cannot be set up.
 */
#include <errno.h>
#include <seccomp.h>
#include <stdio.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

int main(int argc, char **argv) {
    if (argc < 4) {
        fprintf(stderr, "usage: %s ALLOWED_FILE [--mdwx] -- COMMAND [ARGS...]\n", argv[0]);
        return 125;
    }
    int i = 2, mdwx = 0;
    if (strcmp(argv[i], "--mdwx") == 0) {
        mdwx = 1;
        i++;
    }
    if (i >= argc || strcmp(argv[i], "--") != 0 || i + 1 >= argc) {
        fprintf(stderr, "seccomp_exec: expected -- COMMAND\n");
        return 125;
    }
    FILE *f = fopen(argv[1], "r");
    if (!f) {
        perror("seccomp_exec: allowed list");
        return 125;
    }
    scmp_filter_ctx ctx = seccomp_init(SCMP_ACT_ERRNO(EPERM));
    if (!ctx)
        return 125;
    char line[128];
    int allowed = 0;
    while (fgets(line, sizeof line, f)) {
        line[strcspn(line, "\r\n")] = 0;
        if (!line[0])
            continue;
        int nr = seccomp_syscall_resolve_name(line);
        if (nr == __NR_SCMP_ERROR)
            continue;
        if (mdwx && (strcmp(line, "mmap") == 0 || strcmp(line, "mprotect") == 0 ||
                     strcmp(line, "pkey_mprotect") == 0))
            continue; /* added below with conditions */
        if (seccomp_rule_add(ctx, SCMP_ACT_ALLOW, nr, 0) != 0) {
            fprintf(stderr, "seccomp_exec: cannot allow %s\n", line);
            return 125;
        }
        allowed++;
    }
    fclose(f);
    if (mdwx) {
        const unsigned wx = PROT_WRITE | PROT_EXEC;
        int nr_mmap = seccomp_syscall_resolve_name("mmap");
        int nr_mprotect = seccomp_syscall_resolve_name("mprotect");
        int nr_pkey = seccomp_syscall_resolve_name("pkey_mprotect");
        /* allowed unless the flags say write+exec (mmap) or exec (mprotect) */
        if (seccomp_rule_add(ctx, SCMP_ACT_ALLOW, nr_mmap, 1,
                             SCMP_A2(SCMP_CMP_MASKED_EQ, wx, 0)) != 0 ||
            seccomp_rule_add(ctx, SCMP_ACT_ALLOW, nr_mmap, 1,
                             SCMP_A2(SCMP_CMP_MASKED_EQ, wx, PROT_WRITE)) != 0 ||
            seccomp_rule_add(ctx, SCMP_ACT_ALLOW, nr_mmap, 1,
                             SCMP_A2(SCMP_CMP_MASKED_EQ, wx, PROT_EXEC)) != 0 ||
            seccomp_rule_add(ctx, SCMP_ACT_ALLOW, nr_mprotect, 1,
                             SCMP_A2(SCMP_CMP_MASKED_EQ, PROT_EXEC, 0)) != 0 ||
            (nr_pkey != __NR_SCMP_ERROR &&
             seccomp_rule_add(ctx, SCMP_ACT_ALLOW, nr_pkey, 1,
                              SCMP_A2(SCMP_CMP_MASKED_EQ, PROT_EXEC, 0)) != 0)) {
            fprintf(stderr, "seccomp_exec: cannot add the W^X rules\n");
            return 125;
        }
    }
    if (allowed < 50) {
        fprintf(stderr, "seccomp_exec: only %d allowed calls; refusing\n", allowed);
        return 125;
    }
    if (seccomp_load(ctx) != 0) {
        fprintf(stderr, "seccomp_exec: seccomp_load failed\n");
        return 125;
    }
    seccomp_release(ctx);
    execvp(argv[i + 1], argv + i + 1);
    perror("seccomp_exec: exec");
    return 126;
}
