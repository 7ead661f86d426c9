/* The burst executor: runs a plan of half-duplex transactions on a file descriptor, without the GIL.
 *
 * The line engine (ics35_async.engine) makes the plan and keeps every rule; this only moves bytes
 * and reads the clock.  For each transaction of the plan: write its bytes, read until exactly its
 * expected count has come or its deadline passes, and note when its first and last bytes came.  It
 * stops, handing back what it has, at the first transaction that is late, whose bytes differ from
 * the echo of what was sent, that brings more bytes than expected, or that brings a 0xFF while the
 * port marks parity errors (PARMRK: the bytes go to the engine as they came, through the usual
 * decoder), or whose reply is not of the shape its plan entry gives (bytes to compare under a mask,
 * made by the engine's side from the codec: the engine would refuse such a reply, and the plan's
 * later commands must not go out after it); at a transaction boundary once woken; on a hang-up or
 * an error.  It never judges a reply: the engine is fed the bytes and times afterwards and
 * classifies them as it always does.
 *
 * Deadlines follow the engine's own arithmetic: the first transaction's deadline is given; each
 * later one starts when the previous one's last byte came (the time the engine is fed with it) and
 * has its allowance from then.  Times are CLOCK_MONOTONIC seconds (Python's time.monotonic).
 *
 * A Burst runs a plan either in the calling thread (run) or in a thread of its own (start, then
 * result once done_fd is readable), so an event loop can wait for it as for any descriptor.  While
 * it runs, notify(i) makes done_fd readable once transaction i is written, and completed() hands
 * back the transactions already final, so the loop can feed them to the engine while the rest of
 * the plan runs instead of leaving the line idle while it feeds the whole burst at its end.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pthread.h>
#include <stdatomic.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#ifdef __linux__
#include <sched.h>
#include <stdint.h>
#include <sys/eventfd.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#endif

enum { DONE, WOKEN, LATE, MISMATCH, MARK, OVERRUN, HANGUP, FAILED, SHAPE };
#define READ_CHUNK 4096

typedef struct {
    Py_ssize_t tx_off, tx_len;  /* the transaction's bytes in plan_tx */
    Py_ssize_t expect, echo;    /* bytes expected back (echo + reply), of which the echo */
    Py_ssize_t shape_off, shape_len; /* the reply's shape in plan_tx: shape_len bytes wanted, then as
                                        many masks (0: none given) */
    double allowance;           /* seconds from its start to its deadline (the first: unused) */
    /* results */
    Py_ssize_t rx_off, rx_len;  /* its bytes in rx */
    double t_first, t_last;
} Tx;

typedef struct {
    PyObject_HEAD
    int fd;
    int marks;
    int done_r, done_w;  /* readable once a started plan is done */
    atomic_int woken;
    /* the plan and its results */
    Tx *txs;
    Py_ssize_t n, cap;
    unsigned char *plan_tx;
    Py_ssize_t plan_tx_len, plan_tx_cap;
    unsigned char *rx;
    Py_ssize_t rx_cap;
    double first_deadline;
    int status, err;
    _Atomic Py_ssize_t ran;  /* transactions started (written, or being written); every one before the
                                last started is complete and final, and the loop may read it mid-run */
    _Atomic Py_ssize_t notify_at; /* signal done_fd (once) when the transaction of this index is written
                                     (-1: none), so the loop can feed what is complete while the rest runs */
    /* the thread of start() */
    pthread_t thread;
    int has_thread, quit, job, busy;
    pthread_mutex_t lock;
    pthread_cond_t cond;
} Burst;

static double monotonic(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

static void drain(int fd) {
    unsigned char sink[64];
    while (read(fd, sink, sizeof sink) > 0) {
    }
}

/* Wait for fd (events) until the deadline: >0 ready, 0 timed out, -1 error.  A wake is not waited for: it
   stops a plan at its next boundary only (the transaction on the wire is finished first, its deadline at
   most away), where the flag is read; one descriptor less to poll for every read. */
static int wait_for(Burst *self, short events, double deadline, short *revents) {
    struct pollfd p;
    p.fd = self->fd;
    p.events = events;
    p.revents = 0;
    for (;;) {
        double left = deadline - monotonic();
        if (left < 0) left = 0;
#ifdef __linux__
        struct timespec ts;
        ts.tv_sec = (time_t)left;
        ts.tv_nsec = (long)((left - (double)ts.tv_sec) * 1e9);
        int r = ppoll(&p, 1, &ts, NULL);
#else
        int r = poll(&p, 1, (int)(left * 1000.0 + 0.999));
#endif
        if (r < 0) {
            if (errno == EINTR) continue;
            return -1;
        }
        *revents = p.revents;
        return p.revents ? 1 : 0;
    }
}

/* End the plan on an OS error. */
static void stop_failed(Burst *self, int err) {
    self->status = FAILED;
    self->err = err;
}

/* Wait for the line; on an error or a passed deadline, end the plan (status set) and
   return 0, so both the write and the read loop stop the same way. */
static int ready_or_stop(Burst *self, short events, double deadline, short *rev) {
    int r = wait_for(self, events, deadline, rev);
    if (r < 0) {
        stop_failed(self, errno);
        return 0;
    }
    if (r == 0) {
        self->status = LATE;
        return 0;
    }
    return 1;
}

static void signal_fd(int fd);

/* Run the plan (no Python objects touched: called without the GIL). */
static void run_plan(Burst *self) {
    Py_ssize_t rx_len = 0;
    double t_start = 0, deadline = self->first_deadline;
    self->status = DONE;
    self->err = 0;
    atomic_store(&self->ran, 0);
    for (Py_ssize_t i = 0; i < self->n; i++) {
        Tx *t = &self->txs[i];
        if (i > 0) {
            if (atomic_load(&self->woken)) {
                self->status = WOKEN;
                return;
            }
            deadline = t_start + t->allowance;
        }
        t->rx_off = rx_len;
        t->rx_len = 0;
        t->t_first = t->t_last = 0;
        atomic_store_explicit(&self->ran, i + 1, memory_order_release);
        /* write the whole command (a tty takes it at once; otherwise wait until it can) */
        const unsigned char *tx = self->plan_tx + t->tx_off;
        Py_ssize_t sent = 0;
        while (sent < t->tx_len) {
            ssize_t w = write(self->fd, tx + sent, (size_t)(t->tx_len - sent));
            if (w > 0) {
                sent += w;
                continue;
            }
            if (w < 0 && errno == EINTR) continue;
            if (w < 0 && errno != EAGAIN && errno != EWOULDBLOCK) {
                stop_failed(self, errno);
                return;
            }
            short rev = 0;
            if (!ready_or_stop(self, POLLOUT, deadline, &rev)) return;
            if (rev & (POLLERR | POLLNVAL)) {
                stop_failed(self, EIO);
                return;
            }
        }
        /* the loop asked to hear when this one is on the wire: it feeds the engine the transactions
           before it while this one's reply comes */
        Py_ssize_t at = atomic_load(&self->notify_at);
        if (at >= 0 && i >= at && atomic_compare_exchange_strong(&self->notify_at, &at, -1))
            signal_fd(self->done_w);
        /* read until the expected count has come */
        while (t->rx_len < t->expect) {
            short rev = 0;
            if (!ready_or_stop(self, POLLIN, deadline, &rev)) return;
            Py_ssize_t room = self->rx_cap - rx_len;
            if (room > READ_CHUNK) room = READ_CHUNK;
            ssize_t got = read(self->fd, self->rx + rx_len, (size_t)room);
            double now = monotonic();
            if (got < 0) {
                if (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK) continue;
                if (errno == EIO) {
                    /* a tty whose other end went away: Linux answers EIO until the hang-up is
                       complete, then 0 bytes with POLLHUP; either is a hang-up */
                    self->status = HANGUP;
                    return;
                }
                stop_failed(self, errno);
                return;
            }
            if (got == 0) {
                /* a readable tty with nothing to read: hung up (the usual read path tells the
                   hang-up from a flushed input) */
                if (rev & (POLLHUP | POLLERR | POLLNVAL)) {
                    self->status = HANGUP;
                    return;
                }
                continue;
            }
            const unsigned char *chunk = self->rx + rx_len;
            if (!t->rx_len) t->t_first = now;
            t->t_last = now;
            Py_ssize_t before = t->rx_len;
            rx_len += got;
            t->rx_len += got;
            if (self->marks && memchr(chunk, 0xFF, (size_t)got)) {
                self->status = MARK;
                return;
            }
            Py_ssize_t echo_end = t->echo < t->rx_len ? t->echo : t->rx_len;
            if (before < echo_end && memcmp(chunk, tx + before, (size_t)(echo_end - before))) {
                self->status = MISMATCH;
                return;
            }
            if (t->rx_len > t->expect) {
                self->status = OVERRUN;
                return;
            }
        }
        if (t->shape_len) {
            const unsigned char *reply = self->rx + t->rx_off + t->echo;
            const unsigned char *want = self->plan_tx + t->shape_off, *mask = want + t->shape_len;
            for (Py_ssize_t j = 0; j < t->shape_len; j++) {
                if ((reply[j] & mask[j]) != want[j]) {
                    self->status = SHAPE;
                    return;
                }
            }
        }
        t_start = t->t_last;
    }
}

/* ---------------------------------------------------------------- the Python face */

static int make_pipe(int *r, int *w) {
#ifdef __linux__
    int fd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (fd < 0) return -1;
    *r = *w = fd;
    return 0;
#else
    int p[2];
    if (pipe(p) < 0) return -1;
    for (int k = 0; k < 2; k++) {
        fcntl(p[k], F_SETFL, fcntl(p[k], F_GETFL) | O_NONBLOCK);
        fcntl(p[k], F_SETFD, FD_CLOEXEC);
    }
    *r = p[0];
    *w = p[1];
    return 0;
#endif
}

static void signal_fd(int fd) {
#ifdef __linux__
    uint64_t one = 1;
    ssize_t ignored = write(fd, &one, sizeof one);
#else
    unsigned char one = 1;
    ssize_t ignored = write(fd, &one, 1);
#endif
    (void)ignored;
}

static void close_pipe(int *r, int *w) {
    if (*r >= 0) close(*r);
    if (*w >= 0 && *w != *r) close(*w);
    *r = *w = -1;
}

static int Burst_init(Burst *self, PyObject *args, PyObject *kwds) {
    static char *kwlist[] = {"fd", "marks", NULL};
    int fd, marks = 0;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "i|$p", kwlist, &fd, &marks)) return -1;
    if (fd < 0) {
        PyErr_SetString(PyExc_ValueError, "fd must be an open descriptor");
        return -1;
    }
    self->fd = fd;
    self->marks = marks;
    if (self->done_r < 0 && make_pipe(&self->done_r, &self->done_w) < 0) {
        PyErr_SetFromErrno(PyExc_OSError);
        return -1;
    }
    return 0;
}

static PyObject *Burst_new(PyTypeObject *type, PyObject *args, PyObject *kwds) {
    Burst *self = (Burst *)type->tp_alloc(type, 0);
    if (!self) return NULL;
    self->fd = self->done_r = self->done_w = -1;
    atomic_init(&self->woken, 0);
    atomic_init(&self->ran, 0);
    atomic_init(&self->notify_at, -1);
    pthread_mutex_init(&self->lock, NULL);
    pthread_cond_init(&self->cond, NULL);
    return (PyObject *)self;
}

static void stop_thread(Burst *self) {
    if (!self->has_thread) return;
    atomic_store(&self->woken, 1);
    pthread_mutex_lock(&self->lock);
    self->quit = 1;
    pthread_cond_signal(&self->cond);
    pthread_mutex_unlock(&self->lock);
    Py_BEGIN_ALLOW_THREADS
    pthread_join(self->thread, NULL);
    Py_END_ALLOW_THREADS
    self->has_thread = 0;
}

static PyObject *Burst_close(Burst *self, PyObject *unused) {
    stop_thread(self);
    close_pipe(&self->done_r, &self->done_w);
    Py_RETURN_NONE;
}

static void Burst_dealloc(Burst *self) {
    stop_thread(self);
    close_pipe(&self->done_r, &self->done_w);
    PyMem_RawFree(self->txs);
    PyMem_RawFree(self->plan_tx);
    PyMem_RawFree(self->rx);
    pthread_mutex_destroy(&self->lock);
    pthread_cond_destroy(&self->cond);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

/* Copy a plan, [(tx, expect, echo, allowance, shape), ...], into the object's buffers (with the GIL).
   shape: b"" or, for a reply of n = expect - echo bytes, n bytes wanted then n masks. */
static int take_plan(Burst *self, double first_deadline, PyObject *plan) {
    if (self->done_r < 0) {
        PyErr_SetString(PyExc_ValueError, "the burst executor is closed");
        return -1;
    }
    PyObject *seq = PySequence_Fast(plan, "the plan must be a sequence of (tx, expect, echo, allowance, shape)");
    if (!seq) return -1;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    if (n < 1) {
        Py_DECREF(seq);
        PyErr_SetString(PyExc_ValueError, "the plan is empty");
        return -1;
    }
    if (n > self->cap) {
        Tx *txs = PyMem_RawRealloc(self->txs, (size_t)n * sizeof(Tx));
        if (!txs) goto nomem;
        self->txs = txs;
        self->cap = n;
    }
    Py_ssize_t tx_total = 0, rx_total = READ_CHUNK;
    for (Py_ssize_t i = 0; i < n; i++) {
        const char *bytes, *shape;
        Py_ssize_t len, expect, echo, shape_len;
        double allowance;
        PyObject *item = PySequence_Fast_GET_ITEM(seq, i);
        if (!PyTuple_Check(item) ||
            !PyArg_ParseTuple(item, "y#nndy#", &bytes, &len, &expect, &echo, &allowance, &shape, &shape_len)) {
            if (!PyErr_Occurred())
                PyErr_SetString(PyExc_TypeError, "a plan entry is (tx, expect, echo, allowance, shape)");
            Py_DECREF(seq);
            return -1;
        }
        if (len < 1 || expect < 0 || echo < 0 || echo > len || echo > expect) {
            Py_DECREF(seq);
            PyErr_SetString(PyExc_ValueError, "a plan entry needs 0 <= echo <= len(tx), echo <= expect");
            return -1;
        }
        if (shape_len != 0 && shape_len != 2 * (expect - echo)) {
            Py_DECREF(seq);
            PyErr_SetString(PyExc_ValueError, "a plan entry's shape is empty or twice its reply's length");
            return -1;
        }
        if (tx_total + len + shape_len > self->plan_tx_cap) {
            Py_ssize_t cap = (tx_total + len + shape_len) * 2;
            unsigned char *b = PyMem_RawRealloc(self->plan_tx, (size_t)cap);
            if (!b) goto nomem_seq;
            self->plan_tx = b;
            self->plan_tx_cap = cap;
        }
        memcpy(self->plan_tx + tx_total, bytes, (size_t)len);
        Tx *t = &self->txs[i];
        t->tx_off = tx_total;
        t->tx_len = len;
        t->expect = expect;
        t->echo = echo;
        t->allowance = allowance;
        memcpy(self->plan_tx + tx_total + len, shape, (size_t)shape_len);
        t->shape_off = tx_total + len;
        t->shape_len = shape_len / 2;
        tx_total += len + shape_len;
        rx_total += expect;
    }
    Py_DECREF(seq);
    if (rx_total > self->rx_cap) {
        unsigned char *b = PyMem_RawRealloc(self->rx, (size_t)rx_total);
        if (!b) goto nomem;
        self->rx = b;
        self->rx_cap = rx_total;
    }
    self->n = n;
    self->first_deadline = first_deadline;
    atomic_store(&self->notify_at, -1);
    /* none of this plan's transactions has run: completed() before the worker begins must not hand back the
       last plan's records as this one's */
    atomic_store(&self->ran, 0);
    self->status = DONE;
    /* a wake meant for an earlier burst must not cut this one short */
    atomic_store(&self->woken, 0);
    return 0;
nomem_seq:
    Py_DECREF(seq);
nomem:
    PyErr_NoMemory();
    return -1;
}

/* The records of transactions [start, end): (bytes, first, last) each. */
static PyObject *make_records(Burst *self, Py_ssize_t start, Py_ssize_t end) {
    if (start < 0) start = 0;
    if (end < start) end = start;
    PyObject *records = PyList_New(end - start);
    if (!records) return NULL;
    for (Py_ssize_t i = start; i < end; i++) {
        Tx *t = &self->txs[i];
        PyObject *rec = Py_BuildValue("(y#dd)", (const char *)self->rx + t->rx_off, t->rx_len, t->t_first, t->t_last);
        if (!rec) {
            Py_DECREF(records);
            return NULL;
        }
        PyList_SET_ITEM(records, i - start, rec);
    }
    return records;
}

static PyObject *make_result(Burst *self, Py_ssize_t start) {
    PyObject *records = make_records(self, start, atomic_load(&self->ran));
    if (!records) return NULL;
    return Py_BuildValue("(iiN)", self->status, self->err, records);
}

/* The arguments of run() and start(): (first_deadline, plan), taken in while no burst runs.
   Returns -1 with an exception set. */
static int accept_plan(Burst *self, PyObject *args) {
    double first_deadline;
    PyObject *plan;
    if (!PyArg_ParseTuple(args, "dO", &first_deadline, &plan)) return -1;
    if (self->busy) {
        PyErr_SetString(PyExc_RuntimeError, "a burst is already running");
        return -1;
    }
    return take_plan(self, first_deadline, plan);
}

static PyObject *Burst_run(Burst *self, PyObject *args) {
    if (accept_plan(self, args) < 0) return NULL;
    self->busy = 1;
    Py_BEGIN_ALLOW_THREADS
    run_plan(self);
    Py_END_ALLOW_THREADS
    self->busy = 0;
    return make_result(self, 0);
}

#if defined(__linux__) && defined(SYS_sched_setattr)
/* struct sched_attr of sched_setattr(2), its first version (glibc declares it only from 2.41). */
struct slice_request {
    uint32_t size, sched_policy;
    uint64_t sched_flags;
    int32_t sched_nice;
    uint32_t sched_priority;
    uint64_t sched_runtime, sched_deadline, sched_period;
};
#define SHORTEST_SLICE_NS 100000 /* the least the kernel grants (0.1 ms) */
#endif

/* Ask the scheduler for the shortest time slice for this thread, its nice value kept (Linux 6.12 and later;
   older kernels and other systems ignore it).  The executor sleeps on the line between a few microseconds of
   work a transaction; when a reply wakes it, the core is often the program's (its loop feeding the engine a
   frame, a thread of its own), and with the default slice the executor waited for that thread's slice to end
   (hundreds of microseconds, several transactions at 1.25 Mbit/s).  A short slice gives it an earlier deadline,
   so its wake-up preempts; its share of the CPU stays what its use makes it. */
static void ask_short_slice(void) {
#if defined(__linux__) && defined(SYS_sched_setattr)
    struct slice_request attr;
    memset(&attr, 0, sizeof attr);
    attr.size = sizeof attr;
    attr.sched_policy = 0; /* SCHED_OTHER: a program's real-time policy is left alone, below */
    errno = 0;
    int nice = getpriority(PRIO_PROCESS, 0); /* this thread's (Linux): inherited from the one that started it */
    if (nice == -1 && errno) return;
    if (sched_getscheduler(0) != 0) return; /* SCHED_FIFO, SCHED_BATCH...: the program chose; keep it */
    attr.sched_nice = nice;
    attr.sched_runtime = SHORTEST_SLICE_NS;
    (void)syscall(SYS_sched_setattr, 0, &attr, 0); /* refused (a sandbox): the default slice, as before */
#endif
}

static void *worker(void *arg) {
    Burst *self = arg;
    ask_short_slice();
    pthread_mutex_lock(&self->lock);
    for (;;) {
        while (!self->job && !self->quit) pthread_cond_wait(&self->cond, &self->lock);
        if (self->quit) break;
        pthread_mutex_unlock(&self->lock);
        run_plan(self);
        pthread_mutex_lock(&self->lock);
        self->job = 0;
        signal_fd(self->done_w);
    }
    pthread_mutex_unlock(&self->lock);
    return NULL;
}

static PyObject *Burst_start(Burst *self, PyObject *args) {
    if (accept_plan(self, args) < 0) return NULL;
    if (!self->has_thread) {
        self->quit = 0;
        int rc = pthread_create(&self->thread, NULL, worker, self);
        if (rc) {
            errno = rc;
            return PyErr_SetFromErrno(PyExc_OSError);
        }
        self->has_thread = 1;
    }
    drain(self->done_r);
    self->busy = 1;
    pthread_mutex_lock(&self->lock);
    self->job = 1;
    pthread_cond_signal(&self->cond);
    pthread_mutex_unlock(&self->lock);
    Py_RETURN_NONE;
}

static int parse_start(PyObject *args, Py_ssize_t *start) {
    *start = 0;
    return PyArg_ParseTuple(args, "|n", start);
}

static PyObject *Burst_result(Burst *self, PyObject *args) {
    Py_ssize_t start;
    if (!parse_start(args, &start)) return NULL;
    if (!self->busy) {
        PyErr_SetString(PyExc_RuntimeError, "no burst was started");
        return NULL;
    }
    /* Drained before the check, so a notice (see notify) is taken while the burst runs: the signal
       of a burst that ends after the check comes then (the worker sends it after clearing job,
       under the lock).  Drained again once it has ended, as its signal may have come between. */
    drain(self->done_r);
    pthread_mutex_lock(&self->lock);
    int running = self->job;
    pthread_mutex_unlock(&self->lock);
    if (running) Py_RETURN_NONE;
    drain(self->done_r);
    self->busy = 0;
    return make_result(self, start);
}

static PyObject *Burst_wait(Burst *self, PyObject *args) {
    /* Block (without the GIL) until a started burst is done; then its result. */
    if (!self->busy) {
        PyErr_SetString(PyExc_RuntimeError, "no burst was started");
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    pthread_mutex_lock(&self->lock);
    while (self->job) {
        pthread_mutex_unlock(&self->lock);
        struct pollfd p = {self->done_r, POLLIN, 0};
        if (poll(&p, 1, 100) > 0) drain(self->done_r);  /* (a notice: not the end) */
        pthread_mutex_lock(&self->lock);
    }
    pthread_mutex_unlock(&self->lock);
    Py_END_ALLOW_THREADS
    return Burst_result(self, args);
}

static PyObject *Burst_completed(Burst *self, PyObject *args) {
    /* The records from start on that are final while the burst may still run: every transaction
       before the last one started (the last may still be read, or be where the burst stops). */
    Py_ssize_t start;
    if (!parse_start(args, &start)) return NULL;
    if (!self->busy) {
        PyErr_SetString(PyExc_RuntimeError, "no burst was started");
        return NULL;
    }
    return make_records(self, start, atomic_load_explicit(&self->ran, memory_order_acquire) - 1);
}

static PyObject *Burst_notify(Burst *self, PyObject *args) {
    Py_ssize_t index;
    if (!PyArg_ParseTuple(args, "n", &index)) return NULL;
    atomic_store(&self->notify_at, index);
    Py_RETURN_NONE;
}

static PyObject *Burst_wake(Burst *self, PyObject *unused) {
    atomic_store(&self->woken, 1);
    Py_RETURN_NONE;
}

static PyObject *Burst_get_done_fd(Burst *self, void *closure) { return PyLong_FromLong(self->done_r); }
static PyObject *Burst_get_busy(Burst *self, void *closure) { return PyBool_FromLong(self->busy); }

static PyMethodDef Burst_methods[] = {
    {"run", (PyCFunction)Burst_run, METH_VARARGS,
     "run(first_deadline, plan) -> (status, errno, records): run the plan in this thread, without the GIL."},
    {"start", (PyCFunction)Burst_start, METH_VARARGS,
     "start(first_deadline, plan): run the plan in the executor's own thread; done_fd turns readable when done."},
    {"result", (PyCFunction)Burst_result, METH_VARARGS,
     "result(start=0) -> (status, errno, records from transaction start on), or None while the started burst still runs."},
    {"wait", (PyCFunction)Burst_wait, METH_VARARGS,
     "wait(start=0) -> (status, errno, records from start on): block until done."},
    {"completed", (PyCFunction)Burst_completed, METH_VARARGS,
     "completed(start) -> records from start on of the transactions final while the burst runs (each one before the last started)."},
    {"notify", (PyCFunction)Burst_notify, METH_VARARGS,
     "notify(index): make done_fd readable once the transaction of that index is written (result() then still says None)."},
    {"wake", (PyCFunction)Burst_wake, METH_NOARGS,
     "wake(): from any thread, stop the running burst at its next transaction boundary."},
    {"close", (PyCFunction)Burst_close, METH_NOARGS, "close(): end the executor's thread and its descriptors."},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef Burst_getset[] = {
    {"done_fd", (getter)Burst_get_done_fd, NULL, "readable once a started burst is done", NULL},
    {"busy", (getter)Burst_get_busy, NULL, "a burst was started and its result not yet taken", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject BurstType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "ics35_async.drivers._burst.Burst",
    .tp_basicsize = sizeof(Burst),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "Burst(fd, *, marks=False): runs plans of transactions on fd (see the module docstring).",
    .tp_new = Burst_new,
    .tp_init = (initproc)Burst_init,
    .tp_dealloc = (destructor)Burst_dealloc,
    .tp_methods = Burst_methods,
    .tp_getset = Burst_getset,
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT,
    .m_name = "ics35_async.drivers._burst",
    .m_doc = "The burst executor: a plan of transactions run on a descriptor without the GIL.",
    .m_size = -1,
};

PyMODINIT_FUNC PyInit__burst(void) {
    if (PyType_Ready(&BurstType) < 0) return NULL;
    PyObject *m = PyModule_Create(&module);
    if (!m) return NULL;
    Py_INCREF(&BurstType);
    if (PyModule_AddObject(m, "Burst", (PyObject *)&BurstType) < 0) {
        Py_DECREF(&BurstType);
        Py_DECREF(m);
        return NULL;
    }
    const char *names[] = {"DONE", "WOKEN", "LATE", "MISMATCH", "MARK", "OVERRUN", "HANGUP", "FAILED", "SHAPE"};
    for (int k = 0; k < (int)(sizeof names / sizeof names[0]); k++) {
        if (PyModule_AddIntConstant(m, names[k], k) < 0) {
            Py_DECREF(m);
            return NULL;
        }
    }
    return m;
}
