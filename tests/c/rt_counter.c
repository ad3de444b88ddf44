/* LD_PRELOAD interposer for the real-time test (rt_safety.c): counts calls of the
 * allocator, of pthread locks and of sched_yield while counting is switched on.
 *
 *   cc -shared -fPIC -O1 rt_counter.c -o librt_counter.so -ldl
 *   LD_PRELOAD=./librt_counter.so ./rt_safety
 *
 * The program switches counting on and off and reads the counts through
 * rt_counter_enable / rt_counter_get (looked up with dlsym, so it also runs, and
 * says so, without the interposer). Only calls made through the dynamic linker
 * are seen: the library's, libstdc++'s (operator new -> malloc, std::mutex ->
 * pthread_mutex_lock) and the program's own.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <pthread.h>
#include <sched.h>
#include <stddef.h>
#include <stdlib.h>

static __thread int counting = 0;
static long n_alloc = 0, n_lock = 0, n_yield = 0;

void rt_counter_enable(int on) { counting = on; }
void rt_counter_get(long* alloc, long* lock, long* yield) {
    *alloc = n_alloc;
    *lock = n_lock;
    *yield = n_yield;
}
void rt_counter_clear(void) { n_alloc = n_lock = n_yield = 0; }

#define COUNT(var) \
    do {           \
        if (counting) __atomic_add_fetch(&var, 1, __ATOMIC_RELAXED); \
    } while (0)

/* glibc's own entry points: no dlsym needed (dlsym itself may allocate). */
extern void* __libc_malloc(size_t);
extern void* __libc_calloc(size_t, size_t);
extern void* __libc_realloc(void*, size_t);
extern void* __libc_memalign(size_t, size_t);

void* malloc(size_t n) {
    COUNT(n_alloc);
    return __libc_malloc(n);
}
void* calloc(size_t a, size_t b) {
    COUNT(n_alloc);
    return __libc_calloc(a, b);
}
void* realloc(void* p, size_t n) {
    COUNT(n_alloc);
    return __libc_realloc(p, n);
}
void* aligned_alloc(size_t al, size_t n) {
    COUNT(n_alloc);
    return __libc_memalign(al, n);
}
void* memalign(size_t al, size_t n) {
    COUNT(n_alloc);
    return __libc_memalign(al, n);
}
int posix_memalign(void** p, size_t al, size_t n) {
    COUNT(n_alloc);
    *p = __libc_memalign(al, n);
    return *p ? 0 : 12; /* ENOMEM */
}

typedef int (*mutex_fn)(pthread_mutex_t*);
typedef int (*rw_fn)(pthread_rwlock_t*);
typedef int (*yield_fn)(void);
/* Resolved once at load time (dlsym may allocate: never while counting). */
static mutex_fn real_lock, real_trylock;
static rw_fn real_rdlock, real_wrlock;
static yield_fn real_yield;

__attribute__((constructor)) static void resolve(void) {
    real_lock = (mutex_fn)dlsym(RTLD_NEXT, "pthread_mutex_lock");
    real_trylock = (mutex_fn)dlsym(RTLD_NEXT, "pthread_mutex_trylock");
    real_rdlock = (rw_fn)dlsym(RTLD_NEXT, "pthread_rwlock_rdlock");
    real_wrlock = (rw_fn)dlsym(RTLD_NEXT, "pthread_rwlock_wrlock");
    real_yield = (yield_fn)dlsym(RTLD_NEXT, "sched_yield");
}

int pthread_mutex_lock(pthread_mutex_t* m) {
    COUNT(n_lock);
    return real_lock(m);
}
int pthread_mutex_trylock(pthread_mutex_t* m) {
    COUNT(n_lock);
    return real_trylock(m);
}
int pthread_rwlock_rdlock(pthread_rwlock_t* l) {
    COUNT(n_lock);
    return real_rdlock(l);
}
int pthread_rwlock_wrlock(pthread_rwlock_t* l) {
    COUNT(n_lock);
    return real_wrlock(l);
}
int sched_yield(void) {
    COUNT(n_yield);
    return real_yield();
}
