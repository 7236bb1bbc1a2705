/*
 * Five steps of a board's full computation, compiled (docs/server.md, "How boards are computed").
 *
 * A start at 10,000 submissions ranks 15 boards x 1,000 resamples x 10,000 entries and reads four order
 * statistics of each entry's 1,000 relative-score samples. numpy does both by sorting (its fastest sort, the
 * vectorised quicksort, was a third of the start: BENCHMARKS.md, "The board engine"); neither needs a full sort:
 *
 *   rank_rows        competition ranks (1 + values strictly greater) of each row, by a counting sort into as
 *                    many buckets as the row has values, then a sort within each bucket (a few values each).
 *   order_statistics the values a sort of each row would put at given positions, by selection.
 *
 * Both compare the float64 values themselves, so they give exactly what a sort gives. And three steps numpy
 * takes several passes over, each in one, with the same floating-point operations in the same order:
 *
 *   add_timing_noise      the SplitMix64 draw of every sample's timing noise and its move (numpy: fourteen).
 *   fold_min_max          each resample's minimum and maximum over a tile of entries (numpy: two reductions).
 *   add_weighted_min_max  a metric's weighted share of the relative scores (numpy: eight).
 *
 * So every step gives the same bits as numpy's, on any machine. robobpp.scoring keeps numpy's way as the
 * reference and as the fallback where this module was not built (no C compiler), and
 * tests/scoring/test_kernels.py holds the two equal.
 *
 * Plain C and the buffer protocol: no numpy headers at build time. The GIL is released while they run.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* A bucket of more values than this is sorted by qsort, not insertion (clustered scores, an outlier). */
#define INSERTION_MAX 24

typedef struct {
    double value;
    int32_t column;
} Entry;

/* Descending by value: the best first. Ties keep no particular order (they share a rank). */
static int descending(const void *a, const void *b)
{
    double x = ((const Entry *)a)->value, y = ((const Entry *)b)->value;
    return (x < y) - (x > y);
}

static void sort_bucket(Entry *e, Py_ssize_t n)
{
    if (n > INSERTION_MAX) {
        qsort(e, (size_t)n, sizeof(Entry), descending);
        return;
    }
    for (Py_ssize_t i = 1; i < n; i++) {
        Entry x = e[i];
        Py_ssize_t j = i - 1;
        while (j >= 0 && e[j].value < x.value) {
            e[j + 1] = e[j];
            j--;
        }
        e[j + 1] = x;
    }
}

/*
 * Rank one row of n values (all finite) into out. The bucket of a value is (best - value) * scale,
 * truncated: every step is monotonic (IEEE subtraction and multiplication round monotonically), so a greater
 * value never lands in a later bucket, and equal values land in the same one. Buckets in order, each sorted
 * best first, are the row sorted best first; a value's rank is 1 + the position of the first value equal to
 * it.
 */
static void rank_row(const double *row, int32_t *out, Py_ssize_t n, double best, double worst,
                     int32_t *starts, int32_t *bucket, Entry *sorted)
{
    const Py_ssize_t buckets = n;
    const double scale = best > worst ? (double)(buckets - 1) / (best - worst) : 0.0;
    memset(starts, 0, (size_t)(buckets + 1) * sizeof(int32_t));
    for (Py_ssize_t i = 0; i < n; i++) {
        Py_ssize_t k = (Py_ssize_t)((best - row[i]) * scale);
        if (k > buckets - 1)
            k = buckets - 1;
        bucket[i] = (int32_t)k;
        starts[k + 1]++;
    }
    for (Py_ssize_t k = 0; k < buckets; k++)
        starts[k + 1] += starts[k];
    /* starts[k] moves from bucket k's start to its end (bucket k + 1's start) while it is filled */
    for (Py_ssize_t i = 0; i < n; i++) {
        int32_t at = starts[bucket[i]]++;
        sorted[at].value = row[i];
        sorted[at].column = (int32_t)i;
    }
    Py_ssize_t begin = 0;
    for (Py_ssize_t k = 0; k < buckets; k++) {
        Py_ssize_t end = starts[k];
        if (end - begin > 1)
            sort_bucket(sorted + begin, end - begin);
        begin = end;
    }
    int32_t rank = 1;
    for (Py_ssize_t p = 0; p < n; p++) {
        if (p == 0 || sorted[p].value != sorted[p - 1].value)
            rank = (int32_t)(p + 1);
        out[sorted[p].column] = rank;
    }
}

static int check_length(const Py_buffer *buffer, Py_ssize_t items, Py_ssize_t itemsize, const char *what)
{
    if (items < 0 || buffer->len != items * itemsize) {
        PyErr_Format(PyExc_ValueError, "%s holds %zd bytes where %zd were expected", what, buffer->len,
                     items * itemsize);
        return 0;
    }
    return 1;
}

PyDoc_STRVAR(rank_rows_doc,
             "rank_rows(scores, out, rows, n) -> bool\n\n"
             "Competition ranks (1 + values strictly greater) of each of ``rows`` rows of ``n`` float64 values "
             "(a C-contiguous buffer) into ``out`` (int32, the same shape). False, with ``out`` unspecified, when a "
             "value is not finite.");

static PyObject *rank_rows(PyObject *module, PyObject *args)
{
    Py_buffer scores, out;
    Py_ssize_t rows, n;
    if (!PyArg_ParseTuple(args, "y*w*nn", &scores, &out, &rows, &n))
        return NULL;
    PyObject *result = NULL;
    int32_t *starts = NULL, *bucket = NULL;
    Entry *sorted = NULL;
    if (rows < 0 || n < 0 || n > INT32_MAX - 1 || (n > 0 && rows > PY_SSIZE_T_MAX / 8 / n)) {
        PyErr_SetString(PyExc_ValueError, "rows and n must be non-negative, n below 2**31 - 1");
        goto done;
    }
    if (!check_length(&scores, rows * n, 8, "scores") || !check_length(&out, rows * n, 4, "out"))
        goto done;
    int finite = 1;
    if (n > 0 && rows > 0) {
        starts = PyMem_RawMalloc((size_t)(n + 1) * sizeof(int32_t));
        bucket = PyMem_RawMalloc((size_t)n * sizeof(int32_t));
        sorted = PyMem_RawMalloc((size_t)n * sizeof(Entry));
        if (starts == NULL || bucket == NULL || sorted == NULL) {
            PyErr_NoMemory();
            goto done;
        }
        const double *values = scores.buf;
        int32_t *ranks = out.buf;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t r = 0; r < rows && finite; r++) {
            const double *row = values + r * n;
            double best = row[0], worst = row[0];
            for (Py_ssize_t i = 0; i < n; i++) {
                double x = row[i];
                best = x > best ? x : best;
                worst = x < worst ? x : worst;
                finite &= isfinite(x);
            }
            /* the span must be finite too, or the bucket of a value overflows */
            if (finite && isfinite(best - worst))
                rank_row(row, ranks + r * n, n, best, worst, starts, bucket, sorted);
            else
                finite = 0;
        }
        Py_END_ALLOW_THREADS
    }
    result = PyBool_FromLong(finite);
done:
    PyMem_RawFree(starts);
    PyMem_RawFree(bucket);
    PyMem_RawFree(sorted);
    PyBuffer_Release(&scores);
    PyBuffer_Release(&out);
    return result;
}

/* Below this many values a range is sorted by insertion, not split. */
#define SMALL_RANGE 32
/* Values a split's pivot is chosen among (evenly spaced over the range). */
#define PIVOT_SAMPLE 31
/* Splits of one row before the rest of a range is sorted by qsort (a guard: each split removes at least the
   values equal to its pivot, and a sampled pivot removes most of the range). */
#define MAX_SPLITS 64

static int ascending(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static void insertion_sort(double *v, Py_ssize_t n)
{
    for (Py_ssize_t i = 1; i < n; i++) {
        double x = v[i];
        Py_ssize_t j = i - 1;
        while (j >= 0 && v[j] > x) {
            v[j + 1] = v[j];
            j--;
        }
        v[j + 1] = x;
    }
}

/* v[0, n)'s sample: PIVOT_SAMPLE values evenly spaced over it, sorted. */
static void sorted_sample(const double *v, Py_ssize_t n, double *sample)
{
    for (int i = 0; i < PIVOT_SAMPLE; i++)
        sample[i] = v[(Py_ssize_t)(((double)i + 0.5) * (double)n / PIVOT_SAMPLE)];
    insertion_sort(sample, PIVOT_SAMPLE);
}

/* A pivot a little past the value a sort puts at position ``target`` of v[0, n), away from the range's middle:
   the side the target falls on is then the small one (a split near an end of the range keeps little). */
static double pivot_near(const double *sample, Py_ssize_t n, Py_ssize_t target)
{
    Py_ssize_t at = (Py_ssize_t)(((double)target + 0.5) * PIVOT_SAMPLE / (double)n);
    at += 2 * target < n ? 1 : -1;
    return sample[at < 0 ? 0 : (at >= PIVOT_SAMPLE ? PIVOT_SAMPLE - 1 : at)];
}

/*
 * Copy v[0, n) into spare: the values below ``low`` at its start (``below`` of them), those above ``high``
 * (low <= high) at its end (``above``); the others are dropped. No branch on the comparison: both stores always
 * happen and only one count moves, so the two slots meet only at the last value.
 */
static void split(const double *v, double *spare, Py_ssize_t n, double low, double high, Py_ssize_t *below,
                  Py_ssize_t *above)
{
    Py_ssize_t b = 0, a = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        double x = v[i];
        spare[b] = x;
        spare[n - 1 - a] = x;
        b += x < low;
        a += x > high;
    }
    *below = b;
    *above = a;
}

/*
 * The values a sort of v[0, n) puts at positions ``at`` (ascending, relative to the range's first, ``first``),
 * into ``out``. A split (``split``) copies the range into ``spare`` (n values) as the values below a pivot at its
 * start and those above at its end, without a branch on the comparison (what makes it fast on unpredictable
 * samples); the values equal to the pivot need no place. Each side with a position in it is split again, ``v``
 * now the spare.
 */
static void select_positions(double *v, double *spare, Py_ssize_t n, const int64_t *at, Py_ssize_t picks,
                             Py_ssize_t first, double *out, int splits)
{
    if (picks == 0)
        return;
    if (n <= SMALL_RANGE || splits >= MAX_SPLITS) {
        if (n <= SMALL_RANGE)
            insertion_sort(v, n);
        else
            qsort(v, (size_t)n, sizeof(double), ascending);
        for (Py_ssize_t p = 0; p < picks; p++)
            out[p] = v[at[p] - first];
        return;
    }
    double sample[PIVOT_SAMPLE];
    sorted_sample(v, n, sample);
    Py_ssize_t middle = 0; /* the first position in the range's upper half */
    while (middle < picks && 2 * (at[middle] - first) < n)
        middle++;
    Py_ssize_t below, above;
    if (middle > 0 && middle < picks) {
        /* positions in both halves (an interval's two ends): one pass keeps the values below a pivot past the
           lower positions and those above one before the upper positions, and drops the middle */
        const double low_pivot = pivot_near(sample, n, at[middle - 1] - first);
        const double high_pivot = pivot_near(sample, n, at[middle] - first);
        if (low_pivot < high_pivot) {
            split(v, spare, n, low_pivot, high_pivot, &below, &above);
            if (at[middle - 1] - first < below && at[middle] - first >= n - above) {
                select_positions(spare, v, below, at, middle, first, out, splits + 1);
                select_positions(spare + n - above, v + n - above, above, at + middle, picks - middle,
                                 first + n - above, out + middle, splits + 1);
                return;
            }
        }
        /* a position fell in the middle dropped (the sample misled): split around one pivot instead */
    }
    const double pivot = pivot_near(sample, n, at[picks / 2] - first);
    split(v, spare, n, pivot, pivot, &below, &above);
    const Py_ssize_t equal_end = n - above; /* positions [below, equal_end) hold the pivot */
    Py_ssize_t low = 0;
    while (low < picks && at[low] - first < below)
        low++;
    Py_ssize_t high = low;
    while (high < picks && at[high] - first < equal_end)
        out[high++] = pivot;
    select_positions(spare, v, below, at, low, first, out, splits + 1);
    select_positions(spare + equal_end, v + equal_end, above, at + high, picks - high, first + equal_end,
                     out + high, splits + 1);
}

PyDoc_STRVAR(order_statistics_doc,
             "order_statistics(values, n, positions, out) -> bool\n\n"
             "For each row of ``n`` float64 values (a C-contiguous buffer), the values a sort of the row puts at "
             "``positions`` (int64, ascending, each below ``n``), into ``out`` (float64, rows x positions). False, "
             "with ``out`` unspecified, when a value is NaN.");

static PyObject *order_statistics(PyObject *module, PyObject *args)
{
    Py_buffer values, positions, out;
    Py_ssize_t n;
    if (!PyArg_ParseTuple(args, "y*ny*w*", &values, &n, &positions, &out))
        return NULL;
    PyObject *result = NULL;
    double *work = NULL;
    const Py_ssize_t picks = positions.len / 8;
    const int64_t *at = positions.buf;
    if (n <= 0 || values.len % (n * 8) != 0 || positions.len % 8 != 0) {
        PyErr_SetString(PyExc_ValueError, "values must hold whole rows of n > 0 float64 values");
        goto done;
    }
    const Py_ssize_t rows = values.len / (n * 8);
    if (!check_length(&out, rows * picks, 8, "out"))
        goto done;
    for (Py_ssize_t p = 0; p < picks; p++) {
        if (at[p] < 0 || at[p] >= n || (p > 0 && at[p] < at[p - 1])) {
            PyErr_SetString(PyExc_ValueError, "positions must be ascending, each in [0, n)");
            goto done;
        }
    }
    work = PyMem_RawMalloc((size_t)n * 2 * sizeof(double));
    if (work == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    int ordered = 1;
    const double *source = values.buf;
    double *picked = out.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t r = 0; r < rows && ordered; r++) {
        memcpy(work, source + r * n, (size_t)n * sizeof(double));
        for (Py_ssize_t i = 0; i < n; i++)
            ordered &= !isnan(work[i]);
        if (!ordered)
            break;
        select_positions(work, work + n, n, at, picks, 0, picked + r * picks, 0);
    }
    Py_END_ALLOW_THREADS
    result = PyBool_FromLong(ordered);
done:
    PyMem_RawFree(work);
    PyBuffer_Release(&values);
    PyBuffer_Release(&positions);
    PyBuffer_Release(&out);
    return result;
}

/* The element-wise loops worth vectorising (the fold of bounds, the weighted min-max): compiled twice where the
   compiler and the C library can pick a version at load time (GCC or Clang on x86-64 glibc), for AVX2 and for
   any x86-64. The two give the same values: each is IEEE arithmetic in the same order, without fused
   multiply-adds (setup.py), and a minimum or maximum is exact. */
#if defined(__x86_64__) && defined(__GLIBC__) && defined(__has_attribute)
#if __has_attribute(target_clones)
#define VECTOR_CLONES __attribute__((target_clones("avx2", "default")))
#endif
#endif
#ifndef VECTOR_CLONES
#define VECTOR_CLONES
#endif

VECTOR_CLONES
static void fold_rows(const double *values, Py_ssize_t rows, Py_ssize_t r, double *low, double *high)
{
    for (Py_ssize_t i = 0; i < rows; i++) {
        const double *row = values + i * r;
        for (Py_ssize_t k = 0; k < r; k++) {
            /* numpy.fmin and fmax: a NaN gives way to a number */
            double x = row[k], a = low[k], b = high[k];
            low[k] = (x < a || a != a) ? x : a;
            high[k] = (x > b || b != b) ? x : b;
        }
    }
}

/* numpy.round(x, 12): x times 10**12, rounded half to even, divided back (numpy's own three steps). */
static inline double round12(double x)
{
    return rint(x * 1e12) / 1e12;
}

/* numpy.maximum: NaN wins. */
static inline double nan_max(double a, double b)
{
    return (a >= b || a != a) ? a : b;
}

/* One metric's share of entries' relative scores (scores.min_max, weighted, added), given each resample's
   anchor (the min for a metric where higher is better, else the max) and span, as min_max makes them. */
VECTOR_CLONES
static void add_weighted(const double *values, Py_ssize_t rows, Py_ssize_t r, const double *anchor,
                         const double *span, double *total, double weight, double floor, int resolved, int up,
                         int finish)
{
    for (Py_ssize_t i = 0; i < rows; i++) {
        const double *row = values + i * r;
        double *out = total + i * r;
        for (Py_ssize_t k = 0; k < r; k++) {
            double v = round12(row[k]);
            if (resolved)
                v = nan_max(v, floor);
            double n = (up ? v - anchor[k] : anchor[k] - v) / span[k];
            /* 0 where the value or the span is unusable: not finite, or a span not above 0 (NaN included) */
            n = (fabs(n) <= DBL_MAX && span[k] > 0) ? n : 0.0;
            double t = out[k] + n * weight;
            out[k] = finish ? round12(t) : t;
        }
    }
}

PyDoc_STRVAR(add_weighted_min_max_doc,
             "add_weighted_min_max(values, lo, hi, total, weight, floor, least, resolved, up, finish) -> None\n\n"
             "total += weight * scores.min_max(values, lo, hi, key), in place, for ``values`` and ``total`` of "
             "entries x resamples and ``lo``, ``hi`` per resample (float64, C-contiguous): the same operations in "
             "the same order, so the same bits. ``resolved``: the metric's min-max has a ``floor`` and a ``least`` "
             "span (scores.RESOLVED); ``up``: higher is better; ``finish``: round the total to 12 decimals after.");

static PyObject *add_weighted_min_max(PyObject *module, PyObject *args)
{
    Py_buffer values, lo, hi, total;
    double weight, floor, least;
    int resolved, up, finish;
    if (!PyArg_ParseTuple(args, "y*y*y*w*dddppp", &values, &lo, &hi, &total, &weight, &floor, &least, &resolved,
                          &up, &finish))
        return NULL;
    PyObject *result = NULL;
    double *bounds = NULL;
    const Py_ssize_t r = lo.len / 8;
    if (r == 0 || lo.len % 8 != 0 || hi.len != lo.len || values.len % lo.len != 0) {
        PyErr_SetString(PyExc_ValueError, "values must hold whole rows of one value per resample of lo and hi");
        goto done;
    }
    if (!check_length(&total, values.len / 8, 8, "total"))
        goto done;
    bounds = PyMem_RawMalloc((size_t)r * 2 * sizeof(double));
    if (bounds == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    const double *low = lo.buf, *high = hi.buf;
    double *anchor = bounds, *span = bounds + r;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t k = 0; k < r; k++) {
        double a = round12(low[k]), b = round12(high[k]);
        if (resolved) {
            a = nan_max(a, floor);
            b = nan_max(b, floor);
            span[k] = nan_max(b - a, least);
        }
        else
            span[k] = b - a;
        anchor[k] = up ? a : b;
    }
    add_weighted(values.buf, values.len / lo.len, r, anchor, span, total.buf, weight, floor, resolved, up, finish);
    Py_END_ALLOW_THREADS
    result = Py_NewRef(Py_None);
done:
    PyMem_RawFree(bounds);
    PyBuffer_Release(&values);
    PyBuffer_Release(&lo);
    PyBuffer_Release(&hi);
    PyBuffer_Release(&total);
    return result;
}

PyDoc_STRVAR(fold_min_max_doc,
             "fold_min_max(values, low, high) -> None\n\n"
             "Fold rows of float64 values (entries x resamples, C-contiguous) into each resample's running minimum "
             "and maximum (``low``, ``high``: one float64 per resample, updated in place), as numpy.fmin and fmax "
             "do: NaN only where every value was NaN. One pass where numpy's reductions made two.");

static PyObject *fold_min_max(PyObject *module, PyObject *args)
{
    Py_buffer values, low, high;
    if (!PyArg_ParseTuple(args, "y*w*w*", &values, &low, &high))
        return NULL;
    PyObject *result = NULL;
    const Py_ssize_t r = low.len / 8;
    if (r == 0 || low.len % 8 != 0 || high.len != low.len || values.len % low.len != 0) {
        PyErr_SetString(PyExc_ValueError, "values must hold whole rows of one value per resample of low and high");
        goto done;
    }
    const Py_ssize_t rows = values.len / low.len;
    Py_BEGIN_ALLOW_THREADS
    fold_rows(values.buf, rows, r, low.buf, high.buf);
    Py_END_ALLOW_THREADS
    result = Py_NewRef(Py_None);
done:
    PyBuffer_Release(&values);
    PyBuffer_Release(&low);
    PyBuffer_Release(&high);
    return result;
}

PyDoc_STRVAR(add_timing_noise_doc,
             "add_timing_noise(times, seeds, rows, share, resolution, golden, mix1, mix2) -> None\n\n"
             "Move Decision Time samples (entries x resamples, float64, C-contiguous), in place, by each entry's "
             "timing noise: time += (share * time + resolution) * u, u in [-1, 1) the SplitMix64 draw (multipliers "
             "golden, mix1, mix2) of the entry's seed (uint64) and the resample's index in the plan (uint64 rows). "
             "The same integer and floating-point steps as stats.timing_noise and scores.add_timing_noise, so the "
             "same bits.");

static PyObject *add_timing_noise(PyObject *module, PyObject *args)
{
    Py_buffer times, seeds, rows;
    double share, resolution;
    unsigned long long golden, mix1, mix2;
    if (!PyArg_ParseTuple(args, "w*y*y*ddKKK", &times, &seeds, &rows, &share, &resolution, &golden, &mix1, &mix2))
        return NULL;
    PyObject *result = NULL;
    const Py_ssize_t e = seeds.len / 8, r = rows.len / 8;
    if (seeds.len % 8 != 0 || rows.len % 8 != 0 || !check_length(&times, e * r, 8, "times"))
        goto done;
    double *t = times.buf;
    const uint64_t *seed = seeds.buf, *row = rows.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < e; i++) {
        double *at = t + i * r;
        for (Py_ssize_t k = 0; k < r; k++) {
            uint64_t z = seed[i] + (row[k] + 1) * golden;
            z = (z ^ (z >> 30)) * mix1;
            z = (z ^ (z >> 27)) * mix2;
            z ^= z >> 31;
            /* below 2**53: exact as a double, and scaling by a power of two is exact */
            double u = (double)(z >> 11) * 0x1p-52 - 1.0;
            double moved = share * at[k];
            moved += resolution;
            moved *= u;
            at[k] += moved;
        }
    }
    Py_END_ALLOW_THREADS
    result = Py_NewRef(Py_None);
done:
    PyBuffer_Release(&times);
    PyBuffer_Release(&seeds);
    PyBuffer_Release(&rows);
    return result;
}

static PyMethodDef methods[] = {
    {"rank_rows", rank_rows, METH_VARARGS, rank_rows_doc},
    {"order_statistics", order_statistics, METH_VARARGS, order_statistics_doc},
    {"add_timing_noise", add_timing_noise, METH_VARARGS, add_timing_noise_doc},
    {"fold_min_max", fold_min_max, METH_VARARGS, fold_min_max_doc},
    {"add_weighted_min_max", add_weighted_min_max, METH_VARARGS, add_weighted_min_max_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_kernels", "Five steps of a board's full computation, compiled.", -1, methods,
};

PyMODINIT_FUNC PyInit__kernels(void)
{
    return PyModule_Create(&module);
}
