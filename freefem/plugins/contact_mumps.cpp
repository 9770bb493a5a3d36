// contact_mumps: one MUMPS instance kept across the Newton steps of a contact
// solve, for FreeFEM scripts.
//
// Why not FreeFEM's MUMPS_seq: every set(K, solver = sparsesolver) starts a new
// MUMPS instance, which orders and analyses the matrix again, and MUMPS's options
// cannot be reached from a script. The
// Newton matrices of one solve often share their sparsity pattern (the contact
// terms move inside a fixed coupling): this plugin keeps the analysis while the
// pattern stays the same and refactorizes numerically only, and it returns MUMPS's
// error code to the script instead of aborting the process.
//
// Script interface (one instance per run, on rank 0 under FreeFem++-mpi: see "The
// processes" below; the matrix is copied, so the script may change or free it after
// the call):
//   int contactMumpsFactor(matrix K, int reuse)
//   int contactMumpsFactor(matrix A, matrix B, int reuse)
//       factorize K, or K = A + B (square, stored in full; an empty B adds nothing). reuse != 0: numeric
//       factorization only when K has the pattern of the last analysis, analysis
//       and factorization otherwise; reuse = 0: analysis every time (what
//       MUMPS_seq does).
//       Returns MUMPS's INFOG(1): 0 on success, < 0 on failure (MUMPS's error code;
//       the factorization is then released; -1001: K not square, stored as a half,
//       or A and B of different sizes; -1002: an empty matrix), > 0 a warning.
//   int contactMumpsSolve(real[int] x, real[int] b)
//       x = K^-1 b with the last factorization; returns INFOG(1) (-1000 when there is
//       no factorization or the sizes differ). With single-precision factors (below)
//       the answer is refined to double precision first.
//   int contactMumpsLowRank(matrix PtT, matrix P, real[int] d, int maxNew)
//       solve from now on with K = Kf + PtT diag(d) P instead of the factorized Kf
//       (PtT: n x nq, P: nq x n, d: one entry per point, 0 where the point's term is
//       the factorized one): the Newton's change of active set, of rank r = the
//       points with d != 0. Woodbury's identity with the capacitance matrix
//       C = diag(1/d) + P K_f^-1 PtT on those points (dense, r x r, LAPACK's LU):
//       x = Kf^-1 (b - PtT_S C^-1 P_S Kf^-1 b), two solves with the factors. The
//       columns P Kf^-1 PtT e_q are computed once per factorization (a sparse
//       right-hand side per point, solved in blocks) and kept for later steps.
//       Returns the number of columns it had to compute (>= 0); -1004 when that
//       would exceed maxNew (nothing done: the caller refactorizes); -1005 when C is
//       singular; -1000 / -1001 as below. All of d zero turns the correction off.
//   int contactMumpsOutOfCore(string dir)
//   int contactMumpsOutOfCore(string dir, real aboveMb)
//       "": factors in memory (the default); else the next factorizations write their
//       factors to files in dir (MUMPS's out-of-core mode, ICNTL(22) = 1, prefix
//       mumps_factors), which MUMPS deletes when the instance is released: always,
//       or with aboveMb > 0 when the analysis predicts more than aboveMb MB of
//       factors (INFOG(20) entries) and dir's file system has twice that free.
//       Returns 0, or -1006 when dir is longer than MUMPS accepts (255 bytes).
//   int contactMumpsOrdering(int mode)
//       the fill-reducing ordering of the next analyses: 0 automatic (below), 1 AMD,
//       2 nested dissection (Scotch; PORD in the MPI build, whose parallel MUMPS has
//       no Scotch). Returns 0, or -1007 for another mode.
//   int contactMumpsPrecision(int mode)
//       the precision of the next factorizations: 0 double, 1 single, 2 automatic
//       (below). Returns 0, or -1009 for another mode.
//   int contactMumpsCompression(real eps)
//       eps > 0: the next factorizations are MUMPS's block low-rank ones (ICNTL(35) =
//       2, dropping parameter CNTL(7) = eps), every solve refined to double precision
//       as for single-precision factors; 0: full rank. Returns 0, -1010 in the
//       sequential build for eps > 0 (Debian's sequential MUMPS crashes in its BLR
//       clustering: core/sparse_solver.idp), -1011 for eps outside [0, 1).
//   int contactMumpsThreads(int n)
//       the threads of the BLAS under MUMPS's dense kernels (OpenBLAS's
//       openblas_set_num_threads, process-wide): n >= 1. Returns the count in force
//       afterwards (1 with Debian's serial OpenBLAS, whatever n), or -1008 when n < 1
//       or the BLAS loaded is not OpenBLAS.
//   int contactMumpsStats(real[int] s)
//       s (resized to kStats) = analyses, numeric factorizations, solves, entries in
//       the factors (INFOG(29)), operations of the last elimination (RINFOG(3)), the
//       last factorization's memory in MB summed over the processes (INFOG(22)), the
//       size n of the last matrix, INFOG(1) of the last call, CPU seconds spent in
//       MUMPS's analyses, numeric factorizations and solves, the low-rank columns
//       computed and their CPU seconds (counts and seconds: process totals), the
//       ordering of the last analysis (MUMPS's INFOG(7): 0 AMD, 3 Scotch, 4 PORD), the
//       operations per matrix entry AMD predicted in the last automatic choice (0
//       without one), the precision of the last factorization (0 double, 1 single),
//       the refinement steps (preconditioned iterations after the first solve,
//       process total), the factorizations redone in double because refinement did
//       not reach double precision (process total), the largest backward error a
//       refinement left (process maximum), the memory of the largest process in the
//       last factorization in MB (INFOG(21)), whether the factors in force are block
//       low-rank (1) or not (0), the entries of the factors with their low-rank
//       blocks compressed (INFOG(35)), whether they are in files (1) or in memory
//       (0), and the order of the largest front (INFOG(11)).
//   int absMatrixProduct(matrix M, real[int] x, real[int] y)
//       y (resized to M.n) = |M| x, the product with M's absolute values, without
//       assembling them (core/gates.idp's round-off bounds); -1 when x.n != M.m.
//   int contactMumpsRelease()
//       frees the instance (the next factorization analyses again).
//   int contactMumpsProcessMemory(real[int] mb)
//       mb (resized to the number of processes) = each process's peak resident memory
//       so far in MB (/proc's VmHWM); returns the number of processes.
// The plugin is also FreeFEM's default sparse solver (sparsesolver, solve): one
// MUMPS instance per matrix on rank 0 alone, with MUMPS_seq's settings (the class
// ScriptMumps below).
//
// The automatic ordering. Nested dissection (Scotch) makes sparser factors than
// approximate minimum degree (AMD) on all but the smallest contact systems (0.45 to
// 0.88 of AMD's operations), but its analysis costs 3 to 7.5 times AMD's, more than
// the numeric factorization of the 2D default scene (analysis 0.18 s against 0.02 s
// with AMD, factorization 0.14 s, at 24k DOFs). The automatic mode analyses with AMD
// first and keeps it unless AMD's predicted elimination operations per matrix entry
// (RINFOG(1) / nnz) exceed kNestedDissectionPays, where it analyses again with
// Scotch: AMD is faster up to about 1250 per entry, the two are within 10 % from
// 2500 to 7700, and Scotch is faster from 8700 on (make bench, bench-ordering:
// results/bench_ordering.csv, the disk on slab and the ball on slab). Debian's
// Scotch orders on one thread per core unless
// SCOTCH_PTHREAD_NUMBER says otherwise: the scripts set it to 1
// (freefem/lib/core/sparse_solver.idp) for reproducible orderings.
//
// Single-precision factors. MUMPS's single-precision factorization (SMUMPS) does
// the same elimination in half the memory and, on the 3D systems, in about half the
// time (dense kernels at twice the width). Its answer alone is good to about
// 1e-7 relative; the plugin refines it to double precision: flexible GMRES in
// double on K (the kept matrix, plus the low-rank correction in force) with the
// single-precision solve (and its Woodbury correction) as the preconditioner, until
// the componentwise backward error max_i |b - K x|_i / (|K| |x| + |b|)_i reaches
// kRefinedError or stops halving. One step of GMRES is one step of iterative
// refinement; GMRES keeps converging where plain refinement would stall (an
// ill-conditioned system, a loose preconditioner). A solve that cannot reach
// kAcceptedError is not returned: the matrix is factorized again in double precision
// and solved exactly, and the rest of the solve (until contactMumpsRelease) stays
// in double precision. The automatic precision takes single precision when the
// first analysis (AMD's, for the automatic ordering) predicts more than kSinglePays
// operations for the elimination, where the factorization dominates the solve;
// below it double precision gives the answer with one solve per step and the
// results stay those of the double-precision solver to the bit. Measured on the
// ball on slab, P2 (AMD's prediction; the refinement takes 4 to 5 steps a solve):
// nx = 16, 1.05e11 operations, single and double equally fast (Newton 4.25 s
// against 4.22 s of CPU, 20 % less peak memory); nx = 30, 6.9e12, the Newton
// 118 s against 182 s and the peak memory 6.1 GB against 9.0 GB.
//
// Block low-rank factors (contactMumpsCompression) are refined the same way: they
// are a looser preconditioner, cheaper to compute and to store, which costs more
// refinement steps (measured: docs/benchmarks.md).
//
// Build: make setup (the Makefile's rules: freefem/plugins/contact_mumps.so with
// FreeFEM's ff-c++ against Debian's libmumps-seq-dev; freefem/plugins/mpi/
// contact_mumps.so with ff-c++ -mpi -DCONTACT_MUMPS_MPI against libmumps-dev).

#include <iostream>
#include <ctime>
#include <cmath>
#include <cfloat>
#include <vector>
#include <algorithm>
#include <cstring>
#include <string>
#include <fstream>
#include <dlfcn.h>
#include <unistd.h>
#include <sys/statvfs.h>
#include "ff++.hpp"
#include "AFunction_ext.hpp"
#ifdef CONTACT_MUMPS_MPI
#include <mpi.h>
#else
#include "mumps_seq/mpi.h"
#endif
#include "dmumps_c.h"
#include "smumps_c.h"

extern "C" {
void dgetrf_(int *m, int *n, double *a, int *lda, int *ipiv, int *info);
void dgetrs_(char *trans, int *n, int *nrhs, double *a, int *lda, int *ipiv, double *b, int *ldb, int *info);
}

namespace {

const int kJobInit = -1, kJobEnd = -2, kJobAnalyse = 1, kJobFactor = 2, kJobSolve = 3;
const int kHostWorks = 1, kUseCommWorld = -987654;
const long kNoFactorization = -1000, kNotSquare = -1001, kNoMatrix = -1002, kTooManyColumns = -1004,
           kSingularCapacitance = -1005, kDirectoryTooLong = -1006, kBadOrdering = -1007,
           kNoThreadControl = -1008, kBadPrecision = -1009, kNoCompression = -1010, kBadCompression = -1011;
const int kOrderingAuto = 0, kOrderingAmd = 1, kOrderingNested = 2;
// ICNTL(7) values: AMD, and the nested dissection of each build (Debian's parallel
// MUMPS has no Scotch: PORD there)
#ifdef CONTACT_MUMPS_MPI
const int kIcntlAmd = 0, kIcntlNested = 4;
#else
const int kIcntlAmd = 0, kIcntlNested = 3;
#endif
const double kNestedDissectionPays = 6000;   // AMD's predicted operations per matrix entry (see above)
const int kColumnBlock = 32;   // right-hand sides per MUMPS solve of the low-rank columns
const int kPrecisionDouble = 0, kPrecisionSingle = 1, kPrecisionAuto = 2;
const double kSinglePays = 1e11;             // predicted elimination operations (see above)
const double kRefinedError = 16 * DBL_EPSILON;    // componentwise backward error the refinement aims at
const double kAcceptedError = 64 * DBL_EPSILON;   // ... and accepts when it stops improving
const int kGmresRestart = 12, kGmresCycles = 6;
const int kStats = 24;

// M.CSR(), its row pointers M.p over entries in row order (columns increasing within
// a row), with the entries put in that order by a counting sort first: CSR() then only
// builds the pointers, and leaves the arrays and the state its own sort would
// ((row, column) pairs are unique: one such order), so FreeFEM's later products with
// M sum in the same order. CSR() alone sorts all entries with a heap sort,
// O(nnz log nnz) with scattered memory accesses, which on the Newton matrices costs
// about as much as MUMPS's numeric factorization; this is a counting sort on rows and
// a sort of each row's few columns, O(nnz).
static void rowPointers(HashMatrix<int, double> &M) {
    typedef HashMatrix<int, double> HM;
    if (M.state == HM::sorted_ij) { M.CSR(); return; }
    const size_t nnz = M.nnz;
    const int n = M.n, base = M.fortran;
    std::vector<size_t> rowStart(n + 1, 0);
    for (size_t k = 0; k < nnz; ++k) ++rowStart[M.i[k] - base + 1];
    for (int r = 0; r < n; ++r) rowStart[r + 1] += rowStart[r];
    std::vector<size_t> order(nnz), next(rowStart.begin(), rowStart.end() - 1);
    for (size_t k = 0; k < nnz; ++k) order[next[M.i[k] - base]++] = k;
    const int *col = M.j;
    for (int r = 0; r < n; ++r)
        std::sort(order.begin() + rowStart[r], order.begin() + rowStart[r + 1],
                  [col](size_t a, size_t b) { return col[a] < col[b]; });
    {
        std::vector<int> cols(nnz);
        for (size_t k = 0; k < nnz; ++k) cols[k] = M.j[order[k]];
        std::copy(cols.begin(), cols.end(), M.j);
    }
    {
        std::vector<double> vals(nnz);
        for (size_t k = 0; k < nnz; ++k) vals[k] = M.aij[order[k]];
        std::copy(vals.begin(), vals.end(), M.aij);
    }
    for (int r = 0; r < n; ++r)
        for (size_t k = rowStart[r]; k < rowStart[r + 1]; ++k) M.i[k] = r + base;
    M.ReHash();
    M.state = HM::sorted_ij;
    M.CSR();
}

// The processes. The sequential build (contact_mumps.so) runs in one process. The MPI
// build (mpi/contact_mumps.so, for FreeFem++-mpi) is loaded by every rank while
// FreeFEM compiles the script, before any statement runs: rank 0 goes on and runs the
// script, every other rank stays in serveRequests and takes part in the Newton's MUMPS
// calls, which rank 0 announces one by one (a Request: the job, the precision and
// MUMPS's control arrays). The matrix, the right-hand sides and the solutions are
// centralized on rank 0; MUMPS distributes the factorization and the solves. When
// rank 0's run ends (normally, or by exit(n) from the script), FreeFEM's end hook
// sends the last request and every rank leaves; a rank that dies makes mpirun stop
// the others.
struct Processes {
    int rank = 0, size = 1;
};
Processes processes;

#ifdef CONTACT_MUMPS_MPI
const int kJobQuit = -100, kJobReport = -101;   // requests that are not MUMPS jobs
struct Request {
    int job, single, sym;
    int icntl[60];
    double cntl[15];
    char oocDir[256], oocPrefix[64];
};

// One request from rank 0 to the others. Idle ranks wait for it without spinning
// (Open MPI busy-polls a blocking collective): a non-blocking broadcast tested every
// millisecond, so that a waiting rank takes no CPU from the script on rank 0.
void broadcast(Request &request) {
    MPI_Request pending;
    MPI_Ibcast(&request, sizeof(Request), MPI_BYTE, 0, MPI_COMM_WORLD, &pending);
    if (processes.rank == 0) { MPI_Wait(&pending, MPI_STATUS_IGNORE); return; }
    int done = 0;
    for (MPI_Test(&pending, &done, MPI_STATUS_IGNORE); !done; MPI_Test(&pending, &done, MPI_STATUS_IGNORE))
        usleep(1000);
}
#endif

// This process's peak resident memory in MB (VmHWM), 0 if unknown.
double peakResidentMb() {
    std::ifstream status("/proc/self/status");
    std::string word;
    double kb = 0.;
    while (status >> word)
        if (word == "VmHWM:") { status >> kb; break; }
    return kb / 1024.;
}

// MUMPS in one precision: DMUMPS for double, SMUMPS for float.
template <class Real> struct MumpsApi;
template <> struct MumpsApi<double> {
    typedef DMUMPS_STRUC_C Id;
    static void run(Id *id) { dmumps_c(id); }
};
template <> struct MumpsApi<float> {
    typedef SMUMPS_STRUC_C Id;
    static void run(Id *id) { smumps_c(id); }
};

// Double-precision data as MUMPS's arrays of the instance's precision: the data
// itself for double, a converted copy (in buffer) for float.
inline double *asReal(double *x, size_t n, std::vector<double> &) { return x; }
inline float *asReal(double *x, size_t n, std::vector<float> &buffer) {
    buffer.assign(x, x + n);
    return buffer.data();
}
inline void fromReal(double *, size_t, const std::vector<double> &) {}
inline void fromReal(double *x, size_t n, const std::vector<float> &buffer) { std::copy(buffer.begin(), buffer.begin() + n, x); }

// One MUMPS instance of one precision; the matrix is the plugin's (pattern and
// double values), converted when the instance is single precision. A shared instance
// (the Newton's) runs on every process of the MPI build, the others on this process
// alone.
template <class Real> struct MumpsInstance {
    typename MumpsApi<Real>::Id id;
    bool started = false, shared = false;
    int sym = 0;
    std::vector<Real> values, rhs, rhsSparse;

    int &icntl(int i) { return id.icntl[i - 1]; }
    int infog(int i) const { return id.infog[i - 1]; }
    double rinfog(int i) const { return id.rinfog[i - 1]; }
    // MUMPS reports entry counts beyond the int range as minus millions.
    double count(int i) const { return infog(i) >= 0 ? infog(i) : -1e6 * infog(i); }

    // One MUMPS call, announced to the other processes first when the instance is shared.
    void run() {
#ifdef CONTACT_MUMPS_MPI
        if (shared && processes.size > 1) {
            Request request;
            std::memset(&request, 0, sizeof(request));
            request.job = id.job;
            request.single = sizeof(Real) == sizeof(float);
            request.sym = id.sym;
            std::copy(id.icntl, id.icntl + 60, request.icntl);
            std::copy(id.cntl, id.cntl + 15, request.cntl);
            std::memcpy(request.oocDir, id.ooc_tmpdir, sizeof(request.oocDir));
            std::memcpy(request.oocPrefix, id.ooc_prefix, sizeof(request.oocPrefix));
            broadcast(request);
        }
#endif
        MumpsApi<Real>::run(&id);
    }
    void start() {
        if (started) return;
        std::memset(&id, 0, sizeof(id));
        id.job = kJobInit;
        id.par = kHostWorks;
        id.sym = sym;
#ifdef CONTACT_MUMPS_MPI
        id.comm_fortran = (MUMPS_INT)MPI_Comm_c2f(shared ? MPI_COMM_WORLD : MPI_COMM_SELF);
#else
        id.comm_fortran = kUseCommWorld;
#endif
        run();
        started = true;
    }
    // Errors only, on stdout (ICNTL(4) = 1): the scripts report the code themselves;
    // with FreeFEM's -v 4 or more, MUMPS's statistics and timers too (as MUMPS_seq).
    void quiet() {
        const bool talk = verbosity > 3;
        icntl(1) = 6; icntl(2) = talk ? 6 : 0; icntl(3) = talk ? 6 : 0; icntl(4) = talk ? 2 : 1;
    }
    // One MUMPS job; returns INFOG(1) and adds its CPU seconds (the process's: MUMPS
    // runs on this thread) to seconds.
    long call(int job, double &seconds) {
        quiet();
        id.job = job;
        const std::clock_t t0 = std::clock();
        run();
        seconds += double(std::clock() - t0) / CLOCKS_PER_SEC;
        return infog(1);
    }
    void end() {
        if (started) {
            id.job = kJobEnd;
            run();
        }
        started = false;
        std::vector<Real>().swap(values);
        std::vector<Real>().swap(rhs);
        std::vector<Real>().swap(rhsSparse);
    }
    // The assembled matrix, centralized on the host (the arrays stay the caller's).
    void setMatrix(int n, std::vector<int> &irn, std::vector<int> &jcn, std::vector<double> &a,
                   const std::string &outOfCoreDir) {
        id.n = n;
        id.nnz = (MUMPS_INT8)irn.size();
        id.irn = irn.data();
        id.jcn = jcn.data();
        id.a = asReal(a.data(), a.size(), values);
        icntl(5) = 0;    // assembled matrix
        icntl(18) = 0;   // centralized on the host
        icntl(22) = outOfCoreDir.empty() ? 0 : 1;
        if (!outOfCoreDir.empty()) {
            std::strncpy(id.ooc_tmpdir, outOfCoreDir.c_str(), sizeof(id.ooc_tmpdir) - 1);
            std::strncpy(id.ooc_prefix, "mumps_factors", sizeof(id.ooc_prefix) - 1);
        }
    }
    // MUMPS keeps its own copy of the values once they are factorized.
    void dropValues() { std::vector<Real>().swap(values); }
    // x = factors^-1 x, nrhs dense columns of length n.
    long solve(double *x, int nrhs, double &seconds) {
        const size_t len = (size_t)id.n * nrhs;
        id.nrhs = nrhs;
        id.lrhs = id.n;
        id.rhs = asReal(x, len, rhs);
        icntl(9) = 1;
        icntl(20) = 0;
        const long info = call(kJobSolve, seconds);
        id.rhs = 0;
        fromReal(x, len, rhs);
        return info;
    }
    // x (n x nrhs, dense) = factors^-1 of the sparse right-hand sides (1-based CSC:
    // ptr, rows, vals), exploiting their sparsity in the forward substitution.
    long solveSparse(double *x, int nrhs, std::vector<int> &ptr, std::vector<int> &rows, std::vector<double> &vals,
                     double &seconds) {
        const size_t len = (size_t)id.n * nrhs;
        id.nrhs = nrhs;
        id.lrhs = id.n;
        id.rhs = asReal(x, len, rhs);
        id.nz_rhs = (int)rows.size();
        id.rhs_sparse = asReal(vals.data(), vals.size(), rhsSparse);
        id.irhs_sparse = rows.data();
        id.irhs_ptr = ptr.data();
        icntl(9) = 1;
        icntl(20) = 1;
        const long info = call(kJobSolve, seconds);
        icntl(20) = 0;
        id.rhs = 0; id.rhs_sparse = 0; id.irhs_sparse = 0; id.irhs_ptr = 0; id.nz_rhs = 0;
        fromReal(x, len, rhs);
        return info;
    }
};

struct ContactMumps {
    MumpsInstance<double> dbl;
    MumpsInstance<float> sgl;
    ContactMumps() { dbl.shared = sgl.shared = true; }
    bool single = false;        // the factors in force are sgl's
    bool compressed = false;    // ... and block low-rank (compressionEps)
    bool doubleOnly = false;    // refinement failed in this solve: exact double factors until release
    double compressionEps = 0;  // MUMPS's BLR dropping parameter CNTL(7); 0: full rank
    bool factorized = false;
    std::vector<int> irn, jcn;       // the analysed pattern, 1-based, row by row
    std::vector<int> rowsNext, colsNext;   // the pattern being loaded
    std::vector<size_t> rowStart;    // where each row of irn/jcn/values starts
    std::vector<double> values;      // K's values (kept for the refinement's products)
    long analyses = 0, factorizations = 0, solves = 0, lastInfo = 0, columnsSolved = 0;
    long refinementSteps = 0, doubleFallbacks = 0;
    double largestRefinedError = 0;
    int orderingMode = kOrderingAuto, precisionMode = kPrecisionDouble;
    double amdOperationsPerEntry = 0;   // of the last automatic choice
    double analysisSeconds = 0, factorSeconds = 0, solveSeconds = 0, columnSeconds = 0;   // CPU, MUMPS calls only

    // Low-rank correction (contactMumpsLowRank): the kept columns g_q = P Kf^-1 PtT e_q
    // (columnOf[q] indexes columns), and the correction in force: its points S, d on
    // S, the LU of C, P's rows and PtT's columns on S.
    // Out of core (contactMumpsOutOfCore): the factors' folder, and whether they go there
    // always, or when MUMPS predicts more than outOfCoreAboveMb of them and the folder
    // has twice that free (0: never automatically); outOfCore: the factors in force.
    std::string outOfCoreDir;
    bool outOfCoreAlways = false, outOfCore = false;
    double outOfCoreAboveMb = 0;
    std::vector<int> columnOf;
    std::vector<std::vector<double> > columns;
    std::vector<int> corrPoints, corrPivots;
    std::vector<double> corrD, corrLu;
    std::vector<int> corrRowStart, corrRowCol;   // P_S as CSR
    std::vector<double> corrRowVal;
    std::vector<int> corrUpRow, corrUpPoint;     // PtT_S as triplets (row, position in S, value)
    std::vector<double> corrUpVal;

    void dropCorrection() {
        corrPoints.clear(); corrPivots.clear(); corrD.clear(); corrLu.clear();
        corrRowStart.clear(); corrRowCol.clear(); corrRowVal.clear();
        corrUpRow.clear(); corrUpPoint.clear(); corrUpVal.clear();
    }
    void dropColumns() { columnOf.clear(); columns.clear(); dropCorrection(); }

    int n() const { return single ? sgl.id.n : dbl.id.n; }
    bool started() const { return dbl.started || sgl.started; }

    void release() {
        dbl.end();
        sgl.end();
        single = compressed = doubleOnly = factorized = false;
        irn.clear(); jcn.clear(); values.clear(); rowsNext.clear(); colsNext.clear(); rowStart.clear();
        dropColumns();
    }
    ~ContactMumps() { release(); }

    // K = A + B (B may be absent) row by row, columns in increasing order, 1-based:
    // the union of the two patterns, merged row by row (CSR() sorts each matrix by
    // row, then column). True when the pattern is the analysed one. Summing here
    // spares the script a FreeFEM matrix sum, which hashes every entry.
    bool load(HashMatrix<int, double> &A, HashMatrix<int, double> *B) {
        rowPointers(A);
        if (B) rowPointers(*B);
        const int size = A.n;
        rowsNext.clear(); colsNext.clear(); values.clear();
        const size_t reserve = A.nnz + (B ? B->nnz : 0);
        rowsNext.reserve(reserve); colsNext.reserve(reserve); values.reserve(reserve);
        rowStart.assign(size + 1, 0);
        for (int i = 0; i < size; ++i) {
            rowStart[i] = values.size();
            int ka = A.p[i], kb = B ? B->p[i] : 0;
            const int ea = A.p[i + 1], eb = B ? B->p[i + 1] : 0;
            while (ka < ea || kb < eb) {
                int col;
                double v;
                if (kb >= eb || (ka < ea && A.j[ka] < B->j[kb])) { col = A.j[ka]; v = A.aij[ka++]; }
                else if (ka >= ea || B->j[kb] < A.j[ka]) { col = B->j[kb]; v = B->aij[kb++]; }
                else { col = A.j[ka]; v = A.aij[ka++] + B->aij[kb++]; }
                rowsNext.push_back(i + 1);
                colsNext.push_back(col + 1);
                values.push_back(v);
            }
        }
        rowStart[size] = values.size();
        const bool same = started() && n() == size && rowsNext == irn && colsNext == jcn;
        if (!same) { irn.swap(rowsNext); jcn.swap(colsNext); }
        std::vector<int>().swap(rowsNext);
        std::vector<int>().swap(colsNext);
        return same;
    }

    // One analysis on instance m with ordering icntl7 (MUMPS's ICNTL(7)); returns INFOG(1).
    template <class Real> long analyseIn(MumpsInstance<Real> &m, int icntl7, int size) {
        m.start();
        m.setMatrix(size, irn, jcn, values, std::string());
        m.icntl(7) = icntl7;
        compressed = !doubleOnly && compressionEps > 0;
        m.icntl(35) = compressed ? 2 : 0;   // BLR factors (kept compressed for the solves)
        m.id.cntl[6] = compressed ? compressionEps : 0.;
        return lastInfo = m.call(kJobAnalyse, analysisSeconds);
    }

    // MUMPS's analysis in the precision and with the ordering asked (see the top of
    // the file). The automatic choices are made on a first analysis in double
    // precision (with AMD for the automatic ordering); a second analysis follows
    // when they ask for another ordering or for single precision.
    long analyse(int size) {
        dbl.end();
        sgl.end();
        single = !doubleOnly && precisionMode == kPrecisionSingle;
        const int first = orderingMode == kOrderingNested ? kIcntlNested : kIcntlAmd;
        if (single) analyseIn(sgl, first, size);
        else analyseIn(dbl, first, size);
        if (lastInfo < 0) return lastInfo;
        const double operations = single ? sgl.rinfog(1) : dbl.rinfog(1);
        int chosen = first;
        if (orderingMode == kOrderingAuto) {
            amdOperationsPerEntry = operations / double(irn.size());
            if (amdOperationsPerEntry > kNestedDissectionPays) chosen = kIcntlNested;
        }
        const bool toSingle = !single && !doubleOnly && precisionMode == kPrecisionAuto && operations > kSinglePays;
        if (toSingle) {
            dbl.end();
            single = true;
            return analyseIn(sgl, chosen, size);
        }
        if (chosen == first) return lastInfo;
        return single ? analyseIn(sgl, chosen, size) : analyseIn(dbl, chosen, size);
    }

    // Whether the factors MUMPS's analysis predicts for instance m go to files.
    template <class Real> bool factorsOutOfCore(const MumpsInstance<Real> &m) const {
        if (outOfCoreDir.empty()) return false;
        if (outOfCoreAlways) return true;
        const double mb = m.count(20) * sizeof(Real) / 1e6;   // INFOG(20): predicted entries
        struct statvfs fs;
        if (!(outOfCoreAboveMb > 0 && mb > outOfCoreAboveMb) || statvfs(outOfCoreDir.c_str(), &fs) != 0) return false;
        return double(fs.f_bavail) * fs.f_frsize / 1e6 > 2 * mb;
    }

    template <class Real> long factorWith(MumpsInstance<Real> &m) {
        outOfCore = factorsOutOfCore(m);
        m.setMatrix(m.id.n, irn, jcn, values, outOfCore ? outOfCoreDir : std::string());
        lastInfo = m.call(kJobFactor, factorSeconds);
        m.dropValues();
        return lastInfo;
    }

    long factor(HashMatrix<int, double> &A, HashMatrix<int, double> *B, bool reuse) {
        if (A.n != A.m || A.half) return lastInfo = kNotSquare;
        if (B && (B->n != A.n || B->m != A.m || B->half)) return lastInfo = kNotSquare;
        dropColumns();
        const bool same = load(A, B) && reuse;
        if (!same || !factorized) {
            if (analyse(A.n) < 0) { release(); return lastInfo; }
            ++analyses;
        }
        factorized = false;
        if (single && factorWith(sgl) < 0) {
            // single precision could not factorize (e.g. a pivot below its range): double
            doubleOnly = true;
            ++doubleFallbacks;
            if (analyse(A.n) < 0) { release(); return lastInfo; }
            ++analyses;
        }
        if (!single && factorWith(dbl) < 0) { release(); return lastInfo; }
        ++factorizations;
        factorized = true;
        return lastInfo;
    }

    // x = Kf^-1 x in place, nrhs columns, with the factors in force.
    long factorSolve(double *x, int nrhs) {
        lastInfo = single ? sgl.solve(x, nrhs, solveSeconds) : dbl.solve(x, nrhs, solveSeconds);
        if (lastInfo >= 0) ++solves;
        return lastInfo;
    }

    // x = M^-1 x in place: the factors' solve, with the Woodbury correction in force
    // (exact K^-1 with double-precision factors). Woodbury: w = C^-1 P_S y, then
    // x = Kf^-1 (b - PtT_S w).
    long applyInverse(double *x) {
        const int size = n();
        std::vector<double> b;
        if (!corrPoints.empty()) b.assign(x, x + size);
        if (factorSolve(x, 1) < 0 || corrPoints.empty()) return lastInfo;
        int r = (int)corrPoints.size(), one = 1, info = 0;
        std::vector<double> w(r, 0.);
        for (int a = 0; a < r; ++a)
            for (int k = corrRowStart[a]; k < corrRowStart[a + 1]; ++k) w[a] += corrRowVal[k] * x[corrRowCol[k]];
        char notrans = 'N';
        dgetrs_(&notrans, &r, &one, corrLu.data(), &r, corrPivots.data(), w.data(), &r, &info);
        std::copy(b.begin(), b.end(), x);
        for (size_t k = 0; k < corrUpRow.size(); ++k) x[corrUpRow[k]] -= corrUpVal[k] * w[corrUpPoint[k]];
        return factorSolve(x, 1);
    }

    // y = K v (abs: |K| |v|) with K = Kf + PtT_S diag(d_S) P_S, the matrix solved.
    void multiply(const double *v, double *y, bool abs) const {
        const int size = (int)rowStart.size() - 1;
        for (int i = 0; i < size; ++i) {
            double s = 0.;
            for (size_t k = rowStart[i]; k < rowStart[i + 1]; ++k)
                s += (abs ? std::fabs(values[k]) * std::fabs(v[jcn[k] - 1]) : values[k] * v[jcn[k] - 1]);
            y[i] = s;
        }
        if (corrPoints.empty()) return;
        std::vector<double> w(corrPoints.size(), 0.);
        for (size_t a = 0; a < corrPoints.size(); ++a) {
            for (int k = corrRowStart[a]; k < corrRowStart[a + 1]; ++k)
                w[a] += abs ? std::fabs(corrRowVal[k] * v[corrRowCol[k]]) : corrRowVal[k] * v[corrRowCol[k]];
            w[a] *= abs ? std::fabs(corrD[a]) : corrD[a];
        }
        for (size_t k = 0; k < corrUpRow.size(); ++k)
            y[corrUpRow[k]] += abs ? std::fabs(corrUpVal[k]) * w[corrUpPoint[k]] : corrUpVal[k] * w[corrUpPoint[k]];
    }

    // r = b - K x; returns the componentwise backward error max_i |r_i| / (|K||x| + |b|)_i.
    double residual(const double *x, const double *b, std::vector<double> &r) const {
        const size_t size = rowStart.size() - 1;
        std::vector<double> scale(size);
        r.resize(size);
        multiply(x, r.data(), false);
        multiply(x, scale.data(), true);
        double error = 0.;
        for (size_t i = 0; i < size; ++i) {
            r[i] = b[i] - r[i];
            const double s = scale[i] + std::fabs(b[i]);
            if (r[i] != 0.) error = std::max(error, s > 0. ? std::fabs(r[i]) / s : HUGE_VAL);
        }
        return error;
    }

    // Flexible GMRES on K x = b from x (M^-1 b), preconditioned by M (applyInverse),
    // restarted every kGmresRestart steps, until the backward error reaches
    // kRefinedError or a cycle does not halve it. Returns that backward error, or
    // -1 when a solve failed.
    double refine(double *x, const double *b) {
        const int size = n(), m = kGmresRestart;
        std::vector<double> r;
        double error = residual(x, b, r);
        std::vector<std::vector<double> > V(1, std::vector<double>(size)), Z;
        std::vector<double> H((m + 1) * m), cs(m), sn(m), g(m + 1), y(m);
        for (int cycle = 0; cycle < kGmresCycles && error > kRefinedError; ++cycle) {
            double beta = 0.;
            for (double v : r) beta += v * v;
            beta = std::sqrt(beta);
            if (beta == 0.) break;
            for (int i = 0; i < size; ++i) V[0][i] = r[i] / beta;
            std::fill(g.begin(), g.end(), 0.);
            g[0] = beta;
            int steps = 0;
            for (int j = 0; j < m; ++j) {
                if ((int)Z.size() <= j) { Z.emplace_back(size); V.emplace_back(size); }
                Z[j] = V[j];
                if (applyInverse(Z[j].data()) < 0) return -1;
                ++refinementSteps;
                std::vector<double> &w = V[j + 1];
                multiply(Z[j].data(), w.data(), false);
                for (int i = 0; i <= j; ++i) {
                    double h = 0.;
                    for (int k = 0; k < size; ++k) h += w[k] * V[i][k];
                    H[i + j * (m + 1)] = h;
                    for (int k = 0; k < size; ++k) w[k] -= h * V[i][k];
                }
                double norm = 0.;
                for (double v : w) norm += v * v;
                norm = std::sqrt(norm);
                H[j + 1 + j * (m + 1)] = norm;
                if (norm > 0.) for (double &v : w) v /= norm;
                for (int i = 0; i < j; ++i) {
                    const double a = H[i + j * (m + 1)], c = H[i + 1 + j * (m + 1)];
                    H[i + j * (m + 1)] = cs[i] * a + sn[i] * c;
                    H[i + 1 + j * (m + 1)] = -sn[i] * a + cs[i] * c;
                }
                const double a = H[j + j * (m + 1)], c = H[j + 1 + j * (m + 1)], d = std::hypot(a, c);
                cs[j] = d > 0. ? a / d : 1.;
                sn[j] = d > 0. ? c / d : 0.;
                H[j + j * (m + 1)] = d;
                H[j + 1 + j * (m + 1)] = 0.;
                g[j + 1] = -sn[j] * g[j];
                g[j] = cs[j] * g[j];
                steps = j + 1;
                // the estimated residual has dropped far below what the backward error needs
                if (std::fabs(g[j + 1]) <= 1e-10 * beta || norm == 0.) break;
            }
            for (int i = steps - 1; i >= 0; --i) {
                double s = g[i];
                for (int k = i + 1; k < steps; ++k) s -= H[i + k * (m + 1)] * y[k];
                y[i] = s / H[i + i * (m + 1)];
            }
            for (int i = 0; i < steps; ++i)
                for (int k = 0; k < size; ++k) x[k] += y[i] * Z[i][k];
            const double previous = error;
            error = residual(x, b, r);
            if (error > 0.5 * previous) break;
        }
        return error;
    }

    // After a refinement failed: factorize the same K again in double precision and
    // rebuild the correction in force on the new factors.
    long redoInDouble() {
        doubleOnly = true;
        ++doubleFallbacks;
        const int size = n();
        if (analyse(size) < 0) return lastInfo;
        ++analyses;
        if (factorWith(dbl) < 0) return lastInfo;
        ++factorizations;
        if (corrPoints.empty()) { columnOf.assign(columnOf.size(), -1); columns.clear(); return 0; }
        std::vector<int> points = corrPoints;
        std::vector<double> d(columnOf.size(), 0.);
        for (size_t a = 0; a < points.size(); ++a) d[points[a]] = corrD[a];
        columnOf.assign(columnOf.size(), -1);
        columns.clear();
        std::vector<int> want(points.size());
        for (size_t a = 0; a < points.size(); ++a) want[a] = (int)a;
        if (computeColumns(want) < 0) return lastInfo;
        return capacitance() ? 0 : kSingularCapacitance;
    }

    long solve(KN<double> &x, const KN<double> &b) {
        if (!factorized || b.N() != n()) return lastInfo = kNoFactorization;
        const int size = n();
        x.resize(size);
        for (int i = 0; i < size; ++i) x[i] = b[i];
        if (applyInverse((double *)x) < 0 || !(single || compressed)) return lastInfo;
        double error = refine((double *)x, (const double *)b);
        if (error >= 0. && error <= kAcceptedError) {
            largestRefinedError = std::max(largestRefinedError, error);
            return lastInfo;
        }
        if (error < 0. && lastInfo < 0) return lastInfo;
        if (redoInDouble() < 0) { release(); return lastInfo; }
        for (int i = 0; i < size; ++i) x[i] = b[i];
        return applyInverse((double *)x);
    }

    // The columns g_q = P Kf^-1 PtT e_q of the points in want (positions in the
    // correction's points), by blocks of sparse right-hand sides: PtT's columns are
    // the correction's triplets, P's rows on S the correction's rows.
    long computeColumns(const std::vector<int> &want) {
        const int size = n(), nq = (int)columnOf.size();
        std::vector<int> slot(corrPoints.size(), -1);
        for (size_t c = 0; c < want.size(); ++c) slot[want[c]] = (int)c;
        std::vector<std::vector<int> > rowsOf(want.size());
        std::vector<std::vector<double> > valsOf(want.size());
        for (size_t k = 0; k < corrUpRow.size(); ++k) {
            const int c = slot[corrUpPoint[k]];
            if (c >= 0) { rowsOf[c].push_back(corrUpRow[k] + 1); valsOf[c].push_back(corrUpVal[k]); }
        }
        for (size_t c0 = 0; c0 < want.size(); c0 += kColumnBlock) {
            const int nb = (int)std::min<size_t>(kColumnBlock, want.size() - c0);
            std::vector<int> ptr(nb + 1, 1), rows;
            std::vector<double> vals, dense((size_t)size * nb, 0.);
            for (int c = 0; c < nb; ++c) {
                rows.insert(rows.end(), rowsOf[c0 + c].begin(), rowsOf[c0 + c].end());
                vals.insert(vals.end(), valsOf[c0 + c].begin(), valsOf[c0 + c].end());
                ptr[c + 1] = (int)rows.size() + 1;
            }
            if (rows.empty()) { rows.push_back(1); vals.push_back(0.); ptr[nb] = 2; }
            lastInfo = single ? sgl.solveSparse(dense.data(), nb, ptr, rows, vals, columnSeconds)
                              : dbl.solveSparse(dense.data(), nb, ptr, rows, vals, columnSeconds);
            if (lastInfo < 0) return lastInfo;
            for (int c = 0; c < nb; ++c) {
                const double *z = dense.data() + (size_t)c * size;
                std::vector<double> g(nq, 0.);
                for (int q = 0; q < nq; ++q)
                    for (int k = columnRowStart[q]; k < columnRowStart[q + 1]; ++k) g[q] += columnRowVal[k] * z[columnRowCol[k]];
                columnOf[corrPoints[want[c0 + c]]] = (int)columns.size();
                columns.push_back(g);
                ++columnsSolved;
            }
        }
        return 0;
    }
    std::vector<int> columnRowStart, columnRowCol;   // P as CSR (all points), for the columns
    std::vector<double> columnRowVal;

    // The LU of C = diag(1/d) + P Kf^-1 PtT on the correction's points.
    bool capacitance() {
        int r = (int)corrPoints.size(), info = 0;
        corrLu.assign((size_t)r * r, 0.);
        for (int b = 0; b < r; ++b) {
            const std::vector<double> &g = columns[columnOf[corrPoints[b]]];
            for (int a = 0; a < r; ++a) corrLu[a + (size_t)b * r] = g[corrPoints[a]];
            corrLu[b + (size_t)b * r] += 1. / corrD[b];
        }
        corrPivots.assign(r, 0);
        dgetrf_(&r, &r, corrLu.data(), &r, corrPivots.data(), &info);
        return info == 0;
    }

    long lowRank(HashMatrix<int, double> &PtT, HashMatrix<int, double> &P, const KN<double> &d, long maxNew) {
        if (!factorized) return lastInfo = kNoFactorization;
        const int nq = P.n;
        if (P.m != n() || PtT.n != n() || PtT.m != nq || d.N() != nq) return lastInfo = kNotSquare;
        if ((int)columnOf.size() != nq) { columnOf.assign(nq, -1); columns.clear(); }
        dropCorrection();
        std::vector<int> want;   // positions in corrPoints of the points without a column
        for (int q = 0; q < nq; ++q)
            if (d[q] != 0.) {
                if (columnOf[q] < 0) want.push_back((int)corrPoints.size());
                corrPoints.push_back(q);
                corrD.push_back(d[q]);
            }
        if ((long)want.size() > maxNew) { dropCorrection(); return kTooManyColumns; }
        const int r = (int)corrPoints.size();
        if (r == 0) return 0;
        // P's rows and PtT's columns on the correction's points, in one pass each
        std::vector<int> position(nq, -1);
        for (int a = 0; a < r; ++a) position[corrPoints[a]] = a;
        rowPointers(P);
        columnRowStart.assign(P.p, P.p + nq + 1);
        columnRowCol.assign(P.j, P.j + P.nnz);
        columnRowVal.assign(P.aij, P.aij + P.nnz);
        corrRowStart.assign(1, 0);
        for (int a = 0; a < r; ++a) {
            const int q = corrPoints[a];
            for (int k = P.p[q]; k < P.p[q + 1]; ++k) { corrRowCol.push_back(P.j[k]); corrRowVal.push_back(P.aij[k]); }
            corrRowStart.push_back((int)corrRowCol.size());
        }
        for (size_t k = 0; k < (size_t)PtT.nnz; ++k) {
            const int a = position[PtT.j[k]];
            if (a >= 0 && PtT.aij[k] != 0.) { corrUpRow.push_back(PtT.i[k]); corrUpPoint.push_back(a); corrUpVal.push_back(PtT.aij[k]); }
        }
        if (!want.empty() && computeColumns(want) < 0) { dropCorrection(); return lastInfo; }
        if (!capacitance()) { dropCorrection(); return kSingularCapacitance; }
        return (long)want.size();
    }
};

#ifdef CONTACT_MUMPS_MPI
// A rank other than 0: the same MUMPS call as rank 0, on its own instance of the
// request's precision.
template <class Real> void serve(MumpsInstance<Real> &m, const Request &request) {
    if (request.job == kJobInit) {
        std::memset(&m.id, 0, sizeof(m.id));
        m.id.par = kHostWorks;
        m.id.sym = request.sym;
        m.id.comm_fortran = (MUMPS_INT)MPI_Comm_c2f(MPI_COMM_WORLD);
    } else {
        std::copy(request.icntl, request.icntl + 60, m.id.icntl);
        for (int i = 0; i < 15; ++i) m.id.cntl[i] = (Real)request.cntl[i];
        std::memcpy(m.id.ooc_tmpdir, request.oocDir, sizeof(request.oocDir));
        std::memcpy(m.id.ooc_prefix, request.oocPrefix, sizeof(request.oocPrefix));
    }
    m.id.job = request.job;
    MumpsApi<Real>::run(&m.id);
}

// Ranks other than 0 never return from here: they serve rank 0's requests until it
// sends kJobQuit, then leave (FreeFEM's own end would run the script's cleanup).
void serveRequests() {
    MumpsInstance<double> dbl;
    MumpsInstance<float> sgl;
    for (;;) {
        Request request;
        broadcast(request);
        if (request.job == kJobQuit) break;
        if (request.job == kJobReport) {
            double mb = peakResidentMb();
            MPI_Gather(&mb, 1, MPI_DOUBLE, 0, 0, MPI_DOUBLE, 0, MPI_COMM_WORLD);
            continue;
        }
        if (request.single) serve(sgl, request);
        else serve(dbl, request);
    }
    MPI_Finalize();
    _exit(0);
}

// Rank 0's end of the run (FreeFEM's end hook, before its MPI_Finalize): the other
// ranks leave.
void stopOtherRanks() {
    static bool stopped = false;
    int finalized = 0;
    MPI_Finalized(&finalized);
    if (stopped || finalized || processes.size < 2) return;
    stopped = true;
    Request request;
    std::memset(&request, 0, sizeof(request));
    request.job = kJobQuit;
    broadcast(request);
}
#endif

// mb (one entry per process) = each process's peak resident memory in MB so far.
long contactMumpsProcessMemory(KN<double> *const &mb) {
    mb->resize(processes.size);
    (*mb)[0] = peakResidentMb();
#ifdef CONTACT_MUMPS_MPI
    if (processes.size > 1) {
        Request request;
        std::memset(&request, 0, sizeof(request));
        request.job = kJobReport;
        broadcast(request);
        double own = (*mb)[0];
        std::vector<double> all(processes.size);
        MPI_Gather(&own, 1, MPI_DOUBLE, all.data(), 1, MPI_DOUBLE, 0, MPI_COMM_WORLD);
        for (int r = 0; r < processes.size; ++r) (*mb)[r] = all[r];
    }
#endif
    return processes.size;
}

// FreeFEM's sparsesolver (solve, set(A, solver = sparsesolver)) for the scripts' other
// systems (estimators, recovered pressure, tools), one MUMPS instance per matrix on
// this process alone. FreeFEM's MUMPS_seq plugin did this; under FreeFem++-mpi,
// Debian's build of it initialises MPI a second time and aborts the run, so the
// plugin provides it in both builds, with MUMPS_seq's settings (MUMPS's automatic
// ordering, ICNTL(7) = 7; a matrix stored as a half is taken as positive definite,
// SYM = 1) and the matrix in the same order: the sequential build gives MUMPS_seq's
// numbers to the bit.
class ScriptMumps : public VirtualSolver<int, double> {
  public:
    static const int orTypeSol = 1 | 4 | 8 | 16 | 32;
    HashMatrix<int, double> &A;
    MumpsInstance<double> m;
    std::vector<int> irn, jcn;
    std::vector<double> a;
    int symbolicChanges = 0, numericChanges = 0;
    double seconds = 0;

    ScriptMumps(HashMatrix<int, double> &AA, const Data_Sparse_Solver &, Stack) : A(AA) { m.sym = A.half ? 1 : 0; }
    ~ScriptMumps() { m.end(); }

    void check(const char *what) {
        if (m.infog(1) >= 0) return;
        const long info = m.infog(1);
        m.end();
        ExecError((std::string("MUMPS ") + what + " failed, INFOG(1) = " + std::to_string(info)).c_str());
    }
    void fac_init() {
        rowPointers(A);
        irn.resize(A.nnz); jcn.resize(A.nnz); a.resize(A.nnz);
        for (int i = 0; i < A.n; ++i)
            for (int k = A.p[i]; k < A.p[i + 1]; ++k) { irn[k] = i + 1; jcn[k] = A.j[k] + 1; a[k] = A.aij[k]; }
    }
    void fac_symbolic() {
        m.end();
        m.start();
        m.setMatrix(A.n, irn, jcn, a, "");
        m.icntl(7) = 7;
        m.call(kJobAnalyse, seconds);
        check("analysis");
    }
    void fac_numeric() {
        m.setMatrix(A.n, irn, jcn, a, "");
        m.call(kJobFactor, seconds);
        check("factorization");
    }
    void dosolver(double *x, double *b, int N, int trans) {
        std::copy(b, b + (size_t)A.n * N, x);
        m.id.nrhs = N;
        m.id.lrhs = A.n;
        m.id.rhs = x;
        m.icntl(9) = trans ? 0 : 1;
        m.icntl(20) = 0;
        m.call(kJobSolve, seconds);
        m.id.rhs = 0;
        check("solve");
    }
    void UpdateState() {
        if (A.GetReDoNumerics()) ++numericChanges;
        if (A.GetReDoSymbolic()) ++symbolicChanges;
        ChangeCodeState(A.n, symbolicChanges, numericChanges);
    }
};

ContactMumps &instance() {
    static ContactMumps mumps;
    return mumps;
}

long contactMumpsFactor(Matrice_Creuse<double> *const &K, const long &reuse) {
    HashMatrix<int, double> *hm = K ? K->pHM() : 0;
    if (!hm) return instance().lastInfo = kNoMatrix;
    return instance().factor(*hm, 0, reuse != 0);
}

long contactMumpsFactorSum(Matrice_Creuse<double> *const &A, Matrice_Creuse<double> *const &B,
                           const long &reuse) {
    HashMatrix<int, double> *ha = A ? A->pHM() : 0, *hb = B ? B->pHM() : 0;
    if (!ha) return instance().lastInfo = kNoMatrix;
    if (hb && hb->nnz == 0) hb = 0;    // e.g. no contact term yet: K = A
    return instance().factor(*ha, hb, reuse != 0);
}

long contactMumpsSolve(KN<double> *const &x, KN<double> *const &b) {
    return instance().solve(*x, *b);
}

long contactMumpsLowRank(Matrice_Creuse<double> *const &PtT, Matrice_Creuse<double> *const &P,
                         KN<double> *const &d, const long &maxNew) {
    HashMatrix<int, double> *ht = PtT ? PtT->pHM() : 0, *hp = P ? P->pHM() : 0;
    if (!ht || !hp) return instance().lastInfo = kNoMatrix;
    return instance().lowRank(*ht, *hp, *d, maxNew);
}

long contactMumpsOutOfCoreAbove(string *const &dir, const double &aboveMb) {
    ContactMumps &m = instance();
    const std::string d = dir ? *dir : std::string();
    if (d.size() >= sizeof(m.dbl.id.ooc_tmpdir)) return kDirectoryTooLong;
    m.outOfCoreDir = d;
    m.outOfCoreAlways = aboveMb == 0;
    m.outOfCoreAboveMb = aboveMb > 0 ? aboveMb : 0;
    return 0;
}

long contactMumpsOutOfCore(string *const &dir) { return contactMumpsOutOfCoreAbove(dir, 0.); }

long contactMumpsOrdering(const long &mode) {
    if (mode != kOrderingAuto && mode != kOrderingAmd && mode != kOrderingNested) return kBadOrdering;
    instance().orderingMode = (int)mode;
    return 0;
}

// The block low-rank compression of the next factorizations: eps > 0 MUMPS's BLR with
// dropping parameter eps (CNTL(7)), the solves refined to double precision; 0 full
// rank. MPI build only (the sequential library's BLR crashes: core/sparse_solver.idp).
long contactMumpsCompression(const double &eps) {
#ifdef CONTACT_MUMPS_MPI
    if (!(eps >= 0 && eps < 1)) return kBadCompression;
    instance().compressionEps = eps;
    return 0;
#else
    return eps == 0 ? 0 : kNoCompression;
#endif
}

long contactMumpsPrecision(const long &mode) {
    if (mode != kPrecisionDouble && mode != kPrecisionSingle && mode != kPrecisionAuto) return kBadPrecision;
    instance().precisionMode = (int)mode;
    return 0;
}

// OpenBLAS's thread control, looked up at run time in the library MUMPS's LAPACK
// already loaded, so that the plugin links no particular BLAS.
long contactMumpsThreads(const long &n) {
    if (n < 1) return kNoThreadControl;
    void *blas = dlopen("libopenblas.so.0", RTLD_LAZY | RTLD_NOLOAD);
    if (!blas) return kNoThreadControl;
    typedef void (*SetThreads)(int);
    typedef int (*GetThreads)();
    SetThreads setThreads = (SetThreads)dlsym(blas, "openblas_set_num_threads");
    GetThreads getThreads = (GetThreads)dlsym(blas, "openblas_get_num_threads");
    long inForce = kNoThreadControl;
    if (setThreads && getThreads) {
        setThreads((int)n);
        inForce = getThreads();
    }
    dlclose(blas);
    return inForce;
}

template <class Real> void instanceStats(const MumpsInstance<Real> &m, KN<double> &s) {
    s[3] = m.started ? m.count(29) : 0.;
    s[4] = m.started ? m.rinfog(3) : 0.;
    s[5] = m.started ? (double)m.infog(22) : 0.;
    s[6] = m.started ? (double)m.id.n : 0.;
    s[13] = m.started ? (double)m.infog(7) : -1.;
    s[19] = m.started ? (double)m.infog(21) : 0.;
    s[21] = m.started ? m.count(35) : 0.;
    s[23] = m.started ? (double)m.infog(11) : 0.;
}

long contactMumpsStats(KN<double> *const &s) {
    ContactMumps &m = instance();
    s->resize(kStats);
    *s = 0.;
    (*s)[0] = m.analyses;
    (*s)[1] = m.factorizations;
    (*s)[2] = m.solves;
    if (m.single) instanceStats(m.sgl, *s);
    else instanceStats(m.dbl, *s);
    (*s)[7] = m.lastInfo;
    (*s)[8] = m.analysisSeconds;
    (*s)[9] = m.factorSeconds;
    (*s)[10] = m.solveSeconds;
    (*s)[11] = m.columnsSolved;
    (*s)[12] = m.columnSeconds;
    (*s)[14] = m.amdOperationsPerEntry;
    (*s)[15] = m.single ? 1. : 0.;
    (*s)[20] = m.compressed ? 1. : 0.;
    (*s)[22] = m.outOfCore ? 1. : 0.;
    (*s)[16] = m.refinementSteps;
    (*s)[17] = m.doubleFallbacks;
    (*s)[18] = m.largestRefinedError;
    return 0;
}

// y = |M| x, the product with the matrix of M's absolute values (an entry of a half
// stored symmetric matrix counted for both of its places): the round-off bounds of
// core/gates.idp, without assembling |M|. Returns 0, or -1 when the sizes disagree.
long absMatrixProduct(Matrice_Creuse<double> *const &M, KN<double> *const &x, KN<double> *const &y) {
    HashMatrix<int, double> *hm = M ? M->pHM() : 0;
    if (!hm) { y->resize(0); return x->N() == 0 ? 0 : -1; }
    if (x->N() != hm->m) return -1;
    y->resize(hm->n);
    *y = 0.;
    for (size_t k = 0; k < hm->nnz; ++k) {
        const int i = hm->i[k], j = hm->j[k];
        const double a = std::fabs(hm->aij[k]);
        (*y)[i] += a * (*x)[j];
        if (hm->half && i != j) (*y)[j] += a * (*x)[i];
    }
    return 0;
}

long contactMumpsRelease() {
    instance().release();
    return 0;
}

#ifndef CONTACT_MUMPS_MPI
// The sequential MUMPS library talks to a stub MPI that wants to be initialised.
struct StubMpi {
    StubMpi() { int argc = 0; char **argv = 0; MPI_Init(&argc, &argv); }
    ~StubMpi() { MPI_Finalize(); }
};
#endif

}  // namespace

static void Load_Init() {
#ifdef CONTACT_MUMPS_MPI
    int initialized = 0;
    MPI_Initialized(&initialized);
    if (!initialized) {
        std::cerr << "ERROR: freefem/plugins/mpi/contact_mumps is for FreeFem++-mpi (MPI is not initialised)"
                  << std::endl;
        std::exit(4);
    }
    MPI_Comm_rank(MPI_COMM_WORLD, &processes.rank);
    MPI_Comm_size(MPI_COMM_WORLD, &processes.size);
    if (processes.rank > 0) serveRequests();
    ff_atend(stopOtherRanks);
#else
    static StubMpi mpi;
#endif
    addsolver<ScriptMumps>("CONTACTMUMPS", 50, 1);
    setptrstring(def_solver, "CONTACTMUMPS");
    Global.Add("contactMumpsFactor", "(",
               new OneOperator2_<long, Matrice_Creuse<double> *, long>(contactMumpsFactor));
    Global.Add("contactMumpsFactor", "(",
               new OneOperator3_<long, Matrice_Creuse<double> *, Matrice_Creuse<double> *, long>(
                   contactMumpsFactorSum));
    Global.Add("contactMumpsSolve", "(", new OneOperator2_<long, KN<double> *, KN<double> *>(contactMumpsSolve));
    Global.Add("contactMumpsLowRank", "(",
               new OneOperator4_<long, Matrice_Creuse<double> *, Matrice_Creuse<double> *, KN<double> *, long>(
                   contactMumpsLowRank));
    Global.Add("contactMumpsOutOfCore", "(", new OneOperator1_<long, string *>(contactMumpsOutOfCore));
    Global.Add("contactMumpsOutOfCore", "(", new OneOperator2_<long, string *, double>(contactMumpsOutOfCoreAbove));
    Global.Add("contactMumpsOrdering", "(", new OneOperator1_<long, long>(contactMumpsOrdering));
    Global.Add("contactMumpsPrecision", "(", new OneOperator1_<long, long>(contactMumpsPrecision));
    Global.Add("contactMumpsCompression", "(", new OneOperator1_<long, double>(contactMumpsCompression));
    Global.Add("contactMumpsThreads", "(", new OneOperator1_<long, long>(contactMumpsThreads));
    Global.Add("contactMumpsStats", "(", new OneOperator1_<long, KN<double> *>(contactMumpsStats));
    Global.Add("contactMumpsRelease", "(", new OneOperator0<long>(contactMumpsRelease));
    Global.Add("absMatrixProduct", "(",
               new OneOperator3_<long, Matrice_Creuse<double> *, KN<double> *, KN<double> *>(absMatrixProduct));
    Global.Add("contactMumpsProcessMemory", "(", new OneOperator1_<long, KN<double> *>(contactMumpsProcessMemory));
}

LOADFUNC(Load_Init)
