/* The system calls newlib links in the QEMU image. The one that works is _sbrk, for malloc
 * (the native FMU's fmi2Instantiate takes its instance with calloc; newlib-nano's printf of
 * floats takes its conversion buffers the same way): the heap lies between the end of
 * .noinit and the stack's reserve (sections.ld: __heap_start, __heap_limit), beyond it
 * malloc fails. The others are there because abort() and the stdio that vsnprintf links
 * name them; nothing in the firmware opens a file: they fail (and _exit stops the CPU). */
#include <errno.h>
#include <stddef.h>
#include <stdint.h>
#include <sys/stat.h>

extern char __heap_start[], __heap_limit[];
void *_sbrk(ptrdiff_t increment);

void *_sbrk(ptrdiff_t increment) {
    static char *brk = __heap_start;
    if (increment > __heap_limit - brk || increment < __heap_start - brk) {
        errno = ENOMEM;
        return (void *)-1;
    }
    char *old = brk;
    brk += increment;
    return old;
}

struct stat;
void _exit(int status);
int _kill(int pid, int sig);
int _getpid(void);
int _write(int fd, const char *buf, int n);
int _read(int fd, char *buf, int n);
int _close(int fd);
int _fstat(int fd, struct stat *st);
int _isatty(int fd);
int _lseek(int fd, int offset, int whence);

void _exit(int status) {
    (void)status;
    for (;;) __asm volatile("wfi");
}
int _kill(int pid, int sig) {
    (void)pid; (void)sig;
    errno = EINVAL;
    return -1;
}
int _getpid(void) { return 1; }
int _write(int fd, const char *buf, int n) {
    (void)fd; (void)buf; (void)n;
    errno = EBADF;
    return -1;
}
int _read(int fd, char *buf, int n) {
    (void)fd; (void)buf; (void)n;
    errno = EBADF;
    return -1;
}
int _close(int fd) {
    (void)fd;
    errno = EBADF;
    return -1;
}
int _fstat(int fd, struct stat *st) {
    (void)fd; (void)st;
    errno = EBADF;
    return -1;
}
int _isatty(int fd) {
    (void)fd;
    return 0;
}
int _lseek(int fd, int offset, int whence) {
    (void)fd; (void)offset; (void)whence;
    errno = EBADF;
    return -1;
}
