/* The MPI calls of blockflow's MPI transport (scheduler/src/transport/mpi.rs), behind plain C types so
 * that no MPI type crosses into Rust (the Open MPI and MPICH ABIs differ). Compiled with mpicc by
 * build.rs when the `mpi` feature is on. Every function returns an MPI error code (MPI_SUCCESS = 0).
 *
 * One duplicated communicator per message class (0 .. BF_CLASSES - 1), one for collectives and one for
 * aborts, so that messages of different purposes never match each other's receives. */

#include <mpi.h>
#include <stdint.h>
#include <stdlib.h>

#define BF_CLASSES 8

static MPI_Comm bf_class[BF_CLASSES];
static MPI_Comm bf_coll;
static MPI_Comm bf_abort;
static int bf_ready = 0;

/* Initialises MPI for funnelled threads (only the thread that called this calls MPI) and the
 * communicators; the rank, size, the rank among the ranks of this node and their number, and the
 * largest tag. */
int bf_mpi_init(int *rank, int *size, int *local_rank, int *local_size, int *tag_ub, int *provided) {
    int err = MPI_Init_thread(NULL, NULL, MPI_THREAD_FUNNELED, provided);
    if (err != MPI_SUCCESS) return err;
    MPI_Comm_set_errhandler(MPI_COMM_WORLD, MPI_ERRORS_RETURN);
    MPI_Comm_rank(MPI_COMM_WORLD, rank);
    MPI_Comm_size(MPI_COMM_WORLD, size);
    for (int c = 0; c < BF_CLASSES; c++) MPI_Comm_dup(MPI_COMM_WORLD, &bf_class[c]);
    MPI_Comm_dup(MPI_COMM_WORLD, &bf_coll);
    MPI_Comm_dup(MPI_COMM_WORLD, &bf_abort);
    MPI_Comm node;
    MPI_Comm_split_type(MPI_COMM_WORLD, MPI_COMM_TYPE_SHARED, *rank, MPI_INFO_NULL, &node);
    MPI_Comm_rank(node, local_rank);
    MPI_Comm_size(node, local_size);
    MPI_Comm_free(&node);
    int *ub, flag = 0;
    MPI_Comm_get_attr(MPI_COMM_WORLD, MPI_TAG_UB, &ub, &flag);
    *tag_ub = flag ? *ub : 32767;
    bf_ready = 1;
    return MPI_SUCCESS;
}

int bf_mpi_finalize(void) { return MPI_Finalize(); }

/* Starts sending `len` bytes to `to` under `tag` on class `cls`; *req is the request to test. */
int bf_mpi_isend(int cls, int to, int tag, const void *buf, int64_t len, void **req) {
    MPI_Request *r = malloc(sizeof(MPI_Request));
    if (!r) return MPI_ERR_NO_MEM;
    int err = MPI_Isend(buf, (int)len, MPI_BYTE, to, tag, cls < 0 ? bf_abort : bf_class[cls], r);
    if (err != MPI_SUCCESS) {
        free(r);
        return err;
    }
    *req = r;
    return MPI_SUCCESS;
}

/* Whether request `req` has completed (then it is freed). */
int bf_mpi_test(void *req, int *done) {
    MPI_Request *r = req;
    int err = MPI_Test(r, done, MPI_STATUS_IGNORE);
    if (err == MPI_SUCCESS && *done) free(r);
    return err;
}

/* Whether a message of class `cls` (-1: the abort channel) from `from` (-1: any) under `tag` (-1: any)
 * has arrived, with its source, tag and length. */
int bf_mpi_iprobe(int cls, int from, int tag, int *flag, int *source, int *tag_out, int64_t *len) {
    MPI_Status st;
    int err = MPI_Iprobe(from < 0 ? MPI_ANY_SOURCE : from, tag < 0 ? MPI_ANY_TAG : tag,
                         cls < 0 ? bf_abort : bf_class[cls], flag, &st);
    if (err != MPI_SUCCESS || !*flag) return err;
    int count = 0;
    MPI_Get_count(&st, MPI_BYTE, &count);
    *source = st.MPI_SOURCE;
    *tag_out = st.MPI_TAG;
    *len = count;
    return MPI_SUCCESS;
}

/* Receives the message a probe found (source and tag exact). */
int bf_mpi_recv(int cls, int from, int tag, void *buf, int64_t len) {
    return MPI_Recv(buf, (int)len, MPI_BYTE, from, tag, cls < 0 ? bf_abort : bf_class[cls], MPI_STATUS_IGNORE);
}

/* Starts gathering every rank's `len` (one 64-bit length each) into `all` (size entries). */
int bf_mpi_iallgather_len(const int64_t *len, int64_t *all, void **req) {
    MPI_Request *r = malloc(sizeof(MPI_Request));
    if (!r) return MPI_ERR_NO_MEM;
    int err = MPI_Iallgather(len, 1, MPI_INT64_T, all, 1, MPI_INT64_T, bf_coll, r);
    if (err != MPI_SUCCESS) {
        free(r);
        return err;
    }
    *req = r;
    return MPI_SUCCESS;
}

/* Starts gathering every rank's bytes: `counts` and `displs` per rank (size entries each). */
int bf_mpi_iallgatherv(const void *mine, int64_t len, void *all, const int *counts, const int *displs,
                       void **req) {
    MPI_Request *r = malloc(sizeof(MPI_Request));
    if (!r) return MPI_ERR_NO_MEM;
    int err = MPI_Iallgatherv(mine, (int)len, MPI_BYTE, all, counts, displs, MPI_BYTE, bf_coll, r);
    if (err != MPI_SUCCESS) {
        free(r);
        return err;
    }
    *req = r;
    return MPI_SUCCESS;
}

/* Ends the job at once (the last resort when the ranks cannot be told otherwise). */
int bf_mpi_abort(int code) { return MPI_Abort(MPI_COMM_WORLD, code); }
