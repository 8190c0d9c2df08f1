/* Faults injected under a command, for tests/test_faults.py: loaded with LD_PRELOAD, it counts
 * the writes and renames of files under FAULT_DIR and, as the environment asks:
 *   FAULT_WRITE_AT=N        the Nth write there and every later one fail with ENOSPC (a disk
 *                           that fills up at that write);
 *   FAULT_KILL_WRITE_AT=N   the process SIGKILLs itself at the Nth write there;
 *   FAULT_KILL_RENAME=N     it SIGKILLs itself at the Nth rename there of a ".partial-" path,
 *                           before the rename, or after it with FAULT_KILL_AFTER=1;
 *   FAULT_COUNT_FILE=PATH   each process that wrote there appends "writes renames" at exit.
 * Nothing here changes a call that does not touch FAULT_DIR. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/types.h>
#include <sys/uio.h>
#include <unistd.h>

static long writes, renames;

static long setting(const char *name) {
    const char *v = getenv(name);
    return v ? atol(v) : 0;
}

static int under_dir(const char *path) {
    const char *dir = getenv("FAULT_DIR");
    size_t n;
    if (!dir || !path) return 0;
    n = strlen(dir);
    return strncmp(path, dir, n) == 0 && (path[n] == '/' || path[n] == '\0');
}

static int fd_under_dir(int fd) {
    char link[64], path[4096];
    ssize_t n;
    snprintf(link, sizeof link, "/proc/self/fd/%d", fd);
    n = readlink(link, path, sizeof path - 1);
    if (n <= 0) return 0;
    path[n] = '\0';
    return under_dir(path);
}

/* 0: go on; -1: fail this write with ENOSPC. */
static int on_write(int fd) {
    long at, kill_at;
    if (!fd_under_dir(fd)) return 0;
    writes++;
    kill_at = setting("FAULT_KILL_WRITE_AT");
    if (kill_at && writes == kill_at) kill(getpid(), SIGKILL);
    at = setting("FAULT_WRITE_AT");
    if (at && writes >= at) {
        errno = ENOSPC;
        return -1;
    }
    return 0;
}

static int kills_this_rename(const char *old_path) {
    char resolved[4096];
    long at = setting("FAULT_KILL_RENAME");
    const char *p = old_path;
    if (old_path[0] != '/') {
        if (!getcwd(resolved, sizeof resolved)) return 0;
        strncat(resolved, "/", sizeof resolved - strlen(resolved) - 1);
        strncat(resolved, old_path, sizeof resolved - strlen(resolved) - 1);
        p = resolved;
    }
    if (!under_dir(p) || !strstr(old_path, ".partial-")) return 0;
    renames++;
    return at && renames == at;
}

#define REAL(name) static __typeof__(&name) real_##name; if (!real_##name) real_##name = (__typeof__(&name))dlsym(RTLD_NEXT, #name)

ssize_t write(int fd, const void *buf, size_t count) {
    REAL(write);
    if (on_write(fd)) return -1;
    return real_write(fd, buf, count);
}

ssize_t pwrite(int fd, const void *buf, size_t count, off_t offset) {
    REAL(pwrite);
    if (on_write(fd)) return -1;
    return real_pwrite(fd, buf, count, offset);
}

ssize_t pwrite64(int fd, const void *buf, size_t count, off_t offset) {
    REAL(pwrite64);
    if (on_write(fd)) return -1;
    return real_pwrite64(fd, buf, count, offset);
}

ssize_t writev(int fd, const struct iovec *iov, int iovcnt) {
    REAL(writev);
    if (on_write(fd)) return -1;
    return real_writev(fd, iov, iovcnt);
}

ssize_t pwritev(int fd, const struct iovec *iov, int iovcnt, off_t offset) {
    REAL(pwritev);
    if (on_write(fd)) return -1;
    return real_pwritev(fd, iov, iovcnt, offset);
}

static int renamed(int result, int kill_after) {
    if (kill_after && setting("FAULT_KILL_AFTER")) kill(getpid(), SIGKILL);
    return result;
}

int rename(const char *a, const char *b) {
    int k;
    REAL(rename);
    k = kills_this_rename(a);
    if (k && !setting("FAULT_KILL_AFTER")) kill(getpid(), SIGKILL);
    return renamed(real_rename(a, b), k);
}

int renameat(int da, const char *a, int db, const char *b) {
    int k;
    REAL(renameat);
    k = kills_this_rename(a);
    if (k && !setting("FAULT_KILL_AFTER")) kill(getpid(), SIGKILL);
    return renamed(real_renameat(da, a, db, b), k);
}

int renameat2(int da, const char *a, int db, const char *b, unsigned int flags) {
    int k;
    REAL(renameat2);
    k = kills_this_rename(a);
    if (k && !setting("FAULT_KILL_AFTER")) kill(getpid(), SIGKILL);
    return renamed(real_renameat2(da, a, db, b, flags), k);
}

__attribute__((destructor)) static void report(void) {
    const char *path = getenv("FAULT_COUNT_FILE");
    char line[64];
    int fd, n;
    ssize_t (*real)(int, const void *, size_t) = (ssize_t (*)(int, const void *, size_t))dlsym(RTLD_NEXT, "write");
    if (!path || !(writes || renames)) return;
    fd = open(path, O_WRONLY | O_CREAT | O_APPEND, 0644);
    if (fd < 0) return;
    n = snprintf(line, sizeof line, "%ld %ld\n", writes, renames);
    real(fd, line, (size_t)n);
    close(fd);
}
