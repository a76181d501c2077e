/* How tests/data/run_closed_on_a_full_disk.h5.gz was made: a disk full past a file offset, for a writer that is
   LD_PRELOADed with this library (gcc -shared -fPIC -o full_past_offset.so full_past_offset.c -ldl).
   The writer (app.session_file.SessionFile, in-process) wrote one run of 5 lines, called enospc_limit(file size
   + 32) through ctypes, closed the run, and on the write failure ended at once as the writer process does
   (os._exit). recover of that file spun inside HDF5 reading the run's attribute "ended". */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <unistd.h>
#include <sys/types.h>
/* A disk that is full past a file offset: writes below it succeed (pages already allocated), writes past it
   fail with ENOSPC, a write across it is cut there -- as on a tmpfs another program filled. */
static long long limit = -1;
void enospc_limit(long long at) { limit = at; }
static ssize_t (*real_pwrite)(int, const void *, size_t, off_t);
static ssize_t gate(int fd, const void *buf, size_t n, off_t off) {
    if (!real_pwrite) real_pwrite = dlsym(RTLD_NEXT, "pwrite64");
    if (fd > 2 && limit >= 0) {
        if (off >= limit) { errno = ENOSPC; return -1; }
        if (off + (long long)n > limit) n = limit - off;
    }
    return real_pwrite(fd, buf, n, off);
}
ssize_t pwrite(int fd, const void *buf, size_t n, off_t off) { return gate(fd, buf, n, off); }
ssize_t pwrite64(int fd, const void *buf, size_t n, off_t off) { return gate(fd, buf, n, off); }
