/* A helper thread that faults in the heap's fresh pages ahead of the thread that will write
   them. glibc's malloc grows its heap with brk; the first write to each new page costs a page
   fault in which the kernel clears the page (on this project's virtual machine 2.5-3.8 s per
   GiB for memory the guest had not used before). The helper watches the break and populates
   every page below it once, with madvise(MADV_POPULATE_WRITE): the same fault, taken on
   another core, without touching the contents (Linux >= 5.14), so it is safe while the
   other threads use the memory. Loaded by shellobstacle.prefault when malloc keeps its heap
   (it never shrinks it) and a core is spare. */
#define _GNU_SOURCE
#include <errno.h>
#include <pthread.h>
#include <stdint.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>
#ifdef __linux__
#include <sys/syscall.h>
#endif

#define EXPORT __attribute__((visibility("default")))
#ifndef MADV_POPULATE_WRITE
#define MADV_POPULATE_WRITE 23
#endif
#define CHUNK ((size_t)16 << 20)  /* bytes per madvise call */
#define SLEEP_MIN_NS 1000000L     /* poll the break every 1 ms while it moves, */
#define SLEEP_MAX_NS 64000000L    /* backing off to 64 ms while it does not */

static uintptr_t done = 0;           /* the heap is populated below this address */
static long populated = 0, failed = 0; /* bytes populated; errno of a failed madvise */
static int running = 0;

static uintptr_t current_break(void) {
#ifdef __linux__
  return (uintptr_t)syscall(SYS_brk, 0);
#else
  return 0;
#endif
}

static void *watch(void *arg) {
  (void)arg;
  const uintptr_t page = (uintptr_t)sysconf(_SC_PAGESIZE);
  long sleep_ns = SLEEP_MIN_NS;
  for (;;) {
    uintptr_t top = current_break() & ~(page - 1);
    if (top > done) {
      size_t n = top - done < CHUNK ? top - done : CHUNK;
      if (madvise((void *)done, n, MADV_POPULATE_WRITE) != 0) {
        __atomic_store_n(&failed, (long)errno, __ATOMIC_RELAXED);
        __atomic_store_n(&running, 0, __ATOMIC_RELAXED);
        return NULL;
      }
      done += n;
      __atomic_add_fetch(&populated, (long)n, __ATOMIC_RELAXED);
      sleep_ns = SLEEP_MIN_NS;
      continue;
    }
    struct timespec ts = {0, sleep_ns};
    nanosleep(&ts, NULL);
    if (sleep_ns < SLEEP_MAX_NS) sleep_ns *= 2;
  }
}

/* A forked child has no helper thread (fork copies only the calling thread): it starts
   anew if asked, from the child's own break (populating the pages it shares with its parent
   would copy them). */
static void forked_child(void) { __atomic_store_n(&running, 0, __ATOMIC_RELAXED); }

/* Start the helper (once). 0 on success; otherwise the errno of what failed: ENOSYS off
   Linux, EINVAL when the kernel has no MADV_POPULATE_WRITE (tried on one fresh page). */
EXPORT int shellobstacle_prefault_start(void) {
  if (__atomic_load_n(&running, __ATOMIC_RELAXED)) return 0;
  uintptr_t top = current_break();
  if (top == 0) return ENOSYS;
  const long page = sysconf(_SC_PAGESIZE);
  void *probe = mmap(NULL, (size_t)page, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS,
                     -1, 0);
  if (probe == MAP_FAILED) return errno;
  int rc = madvise(probe, (size_t)page, MADV_POPULATE_WRITE) == 0 ? 0 : errno;
  munmap(probe, (size_t)page);
  if (rc != 0) return rc;
  done = (top + (uintptr_t)page - 1) & ~((uintptr_t)page - 1);
  pthread_attr_t attr;
  pthread_t thread;
  pthread_attr_init(&attr);
  pthread_attr_setdetachstate(&attr, PTHREAD_CREATE_DETACHED);
  rc = pthread_create(&thread, &attr, watch, NULL);
  pthread_attr_destroy(&attr);
  if (rc != 0) return rc;
  __atomic_store_n(&running, 1, __ATOMIC_RELAXED);
  static int registered = 0;
  if (!registered) registered = pthread_atfork(NULL, NULL, forked_child) == 0;
  return 0;
}

/* Bytes populated so far by the helper. */
EXPORT long shellobstacle_prefault_bytes(void) {
  return __atomic_load_n(&populated, __ATOMIC_RELAXED);
}

/* Whether the helper thread runs in this process. */
EXPORT int shellobstacle_prefault_running(void) {
  return __atomic_load_n(&running, __ATOMIC_RELAXED);
}

/* 0 while the helper runs or was never started; the errno that stopped it otherwise. */
EXPORT long shellobstacle_prefault_error(void) {
  return __atomic_load_n(&failed, __ATOMIC_RELAXED);
}
