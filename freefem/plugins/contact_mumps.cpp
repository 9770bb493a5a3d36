// contact_mumps: one sequential MUMPS instance kept across the Newton steps of a
// contact solve, for FreeFEM scripts.
//
// Why not FreeFEM's MUMPS_seq: every set(K, solver = sparsesolver) starts a new
// MUMPS instance, which orders and analyses the matrix again, and MUMPS's options
// cannot be reached from a script. The
// Newton matrices of one solve often share their sparsity pattern (the contact
// terms move inside a fixed coupling): this plugin keeps the analysis while the
// pattern stays the same and refactorizes numerically only, and it returns MUMPS's
// error code to the script instead of aborting the process.
//
// Script interface (one instance per process; the matrix is copied, so the script
// may change or free it after the call):
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
//       no factorization or the sizes differ).
//   int contactMumpsStats(real[int] s)
//       s (resized to 11) = analyses, numeric factorizations, solves, entries in the
//       factors (INFOG(29)), operations of the last elimination (RINFOG(3)), the
//       last factorization's peak memory in MB (INFOG(22)), the size n of the last
//       matrix, INFOG(1) of the last call, CPU seconds spent in MUMPS's analyses,
//       numeric factorizations and solves (counts and seconds: process totals).
//   int contactMumpsRelease()
//       frees the instance (the next factorization analyses again).
//
// The ordering stays MUMPS's automatic choice (ICNTL(7) = 7), as in MUMPS_seq, so a
// first factorization matches FreeFEM's own sparsesolver. Debian's Scotch orders on
// one thread per core unless SCOTCH_PTHREAD_NUMBER says otherwise: the scripts set
// it to 1 (freefem/lib/core/sparse_solver.idp) for reproducible orderings.
//
// Build: make setup (the Makefile's rule for freefem/plugins/contact_mumps.so,
// FreeFEM's ff-c++ against Debian's libmumps-seq-dev).

#include <iostream>
#include <ctime>
#include <vector>
#include "ff++.hpp"
#include "mumps_seq/mpi.h"
#include "dmumps_c.h"

namespace {

const int kJobInit = -1, kJobEnd = -2, kJobAnalyse = 1, kJobFactor = 2, kJobSolve = 3;
const int kHostWorks = 1, kUseCommWorld = -987654;
const long kNoFactorization = -1000, kNotSquare = -1001, kNoMatrix = -1002;

struct ContactMumps {
    DMUMPS_STRUC_C id;
    bool started = false, factorized = false;
    std::vector<int> irn, jcn;       // the analysed pattern, 1-based, row by row
    std::vector<int> rowsNext, colsNext;   // the pattern being loaded
    std::vector<double> values;
    long analyses = 0, factorizations = 0, solves = 0, lastInfo = 0;
    double analysisSeconds = 0, factorSeconds = 0, solveSeconds = 0;   // CPU, MUMPS calls only

    int &icntl(int i) { return id.icntl[i - 1]; }
    int infog(int i) const { return id.infog[i - 1]; }
    // MUMPS reports entry counts beyond the int range as minus millions.
    double count(int i) const { return infog(i) >= 0 ? infog(i) : -1e6 * infog(i); }

    // One MUMPS job; returns its CPU seconds (the process's: MUMPS runs on this thread).
    double call(int job) {
        quiet();
        id.job = job;
        const std::clock_t t0 = std::clock();
        dmumps_c(&id);
        lastInfo = infog(1);
        return double(std::clock() - t0) / CLOCKS_PER_SEC;
    }

    void start() {
        if (started) return;
        id.job = kJobInit;
        id.par = kHostWorks;
        id.sym = 0;
        id.comm_fortran = kUseCommWorld;
        dmumps_c(&id);
        quiet();
        started = true;
    }
    // Errors only, on stdout (ICNTL(4) = 1): the scripts report the code themselves;
    // with FreeFEM's -v 4 or more, MUMPS's statistics and timers too (as MUMPS_seq).
    void quiet() {
        const bool talk = verbosity > 3;
        icntl(1) = 6; icntl(2) = talk ? 6 : 0; icntl(3) = talk ? 6 : 0; icntl(4) = talk ? 2 : 1;
    }
    void release() {
        if (started) {
            id.job = kJobEnd;
            dmumps_c(&id);
        }
        started = factorized = false;
        irn.clear(); jcn.clear(); values.clear(); rowsNext.clear(); colsNext.clear();
    }
    ~ContactMumps() { release(); }

    // K = A + B (B may be absent) row by row, columns in increasing order, 1-based:
    // the union of the two patterns, merged row by row (CSR() sorts each matrix by
    // row, then column). True when the pattern is the analysed one. Summing here
    // spares the script a FreeFEM matrix sum, which hashes every entry.
    bool load(HashMatrix<int, double> &A, HashMatrix<int, double> *B) {
        A.CSR();
        if (B) B->CSR();
        const int n = A.n;
        rowsNext.clear(); colsNext.clear(); values.clear();
        const size_t reserve = A.nnz + (B ? B->nnz : 0);
        rowsNext.reserve(reserve); colsNext.reserve(reserve); values.reserve(reserve);
        for (int i = 0; i < n; ++i) {
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
        const bool same = started && id.n == n && rowsNext == irn && colsNext == jcn;
        if (!same) { irn.swap(rowsNext); jcn.swap(colsNext); }
        return same;
    }

    long factor(HashMatrix<int, double> &A, HashMatrix<int, double> *B, bool reuse) {
        if (A.n != A.m || A.half) return lastInfo = kNotSquare;
        if (B && (B->n != A.n || B->m != A.m || B->half)) return lastInfo = kNotSquare;
        start();
        bool same = load(A, B) && reuse;
        id.n = A.n;
        id.nnz = (MUMPS_INT8)irn.size();
        id.irn = irn.data();
        id.jcn = jcn.data();
        id.a = values.data();
        icntl(5) = 0;    // assembled matrix
        icntl(7) = 7;    // automatic ordering
        icntl(18) = 0;   // centralized on the host
        if (!same || !factorized) {
            analysisSeconds += call(kJobAnalyse);
            if (lastInfo < 0) { release(); return lastInfo; }
            ++analyses;
        }
        factorSeconds += call(kJobFactor);
        if (lastInfo < 0) { release(); return lastInfo; }
        ++factorizations;
        factorized = true;
        return lastInfo;
    }

    long solve(KN<double> &x, const KN<double> &b) {
        if (!factorized || b.N() != id.n) return lastInfo = kNoFactorization;
        x.resize(b.N());
        for (int i = 0; i < id.n; ++i) x[i] = b[i];
        id.nrhs = 1;
        id.lrhs = id.n;
        id.rhs = (double *)x;
        icntl(9) = 1;
        solveSeconds += call(kJobSolve);
        id.rhs = 0;
        if (lastInfo >= 0) ++solves;
        return lastInfo;
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

long contactMumpsStats(KN<double> *const &s) {
    ContactMumps &m = instance();
    s->resize(11);
    (*s)[0] = m.analyses;
    (*s)[1] = m.factorizations;
    (*s)[2] = m.solves;
    (*s)[3] = m.started ? m.count(29) : 0.;
    (*s)[4] = m.started ? m.id.rinfog[2] : 0.;
    (*s)[5] = m.started ? (double)m.infog(22) : 0.;
    (*s)[6] = m.started ? (double)m.id.n : 0.;
    (*s)[7] = m.lastInfo;
    (*s)[8] = m.analysisSeconds;
    (*s)[9] = m.factorSeconds;
    (*s)[10] = m.solveSeconds;
    return 0;
}

long contactMumpsRelease() {
    instance().release();
    return 0;
}

// The sequential MUMPS library talks to a stub MPI that wants to be initialised.
struct StubMpi {
    StubMpi() { int argc = 0; char **argv = 0; MPI_Init(&argc, &argv); }
    ~StubMpi() { MPI_Finalize(); }
};

}  // namespace

static void Load_Init() {
    static StubMpi mpi;
    Global.Add("contactMumpsFactor", "(",
               new OneOperator2_<long, Matrice_Creuse<double> *, long>(contactMumpsFactor));
    Global.Add("contactMumpsFactor", "(",
               new OneOperator3_<long, Matrice_Creuse<double> *, Matrice_Creuse<double> *, long>(
                   contactMumpsFactorSum));
    Global.Add("contactMumpsSolve", "(", new OneOperator2_<long, KN<double> *, KN<double> *>(contactMumpsSolve));
    Global.Add("contactMumpsStats", "(", new OneOperator1_<long, KN<double> *>(contactMumpsStats));
    Global.Add("contactMumpsRelease", "(", new OneOperator0<long>(contactMumpsRelease));
}

LOADFUNC(Load_Init)
