#!/usr/bin/env python3
# The lbmpy peer of `blockflow bench kernel`: lbmpy's generated D3Q19 TRT kernel (incompressible, AVX2
# vectorised, OpenMP threads), pull (two arrays) or AA (in place, even and odd kernels alternating), on a
# periodic N x N x (N * threads) array (N^3 cells per thread), the ghost exchange excluded as in blockflow's
# kernel rows. Prints the best of 3 timings in MLUPS.
#   pip install lbmpy==1.3.7
#   OMP_PROC_BIND=true python3 scripts/lbmpy-kernel-bench.py N THREADS f64|f32 pull|aa [STEPS]
import sys, time
import pystencils as ps
from lbmpy import LBMConfig, LBMOptimisation, Method, Stencil, LBStencil, create_lb_update_rule
from lbmpy.advanced_streaming import Timestep

N, T, prec, pattern = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4]
dtype = 'float64' if prec == 'f64' else 'float32'
stencil = LBStencil(Stencil.D3Q19)
# N^3 per thread: split along z
shape = (N, N, N * T)
dh = ps.create_data_handling(domain_size=shape, periodicity=True, default_target=ps.Target.CPU)
src = dh.add_array('src', values_per_cell=19, dtype=dtype, layout='fzyx', alignment=True)
dst = None if pattern == 'aa' else dh.add_array('dst', values_per_cell=19, dtype=dtype, layout='fzyx', alignment=True)
kernels = []
steps_kinds = [Timestep.EVEN, Timestep.ODD] if pattern == 'aa' else [Timestep.BOTH]
for ts in steps_kinds:
    cfg = LBMConfig(stencil=stencil, method=Method.TRT, relaxation_rates=[1.0 / 0.6, 1.6], compressible=False,
                    streaming_pattern=pattern, timestep=ts)
    opt = LBMOptimisation(symbolic_field=src, symbolic_temporary_field=dst, field_layout='fzyx')
    rule = create_lb_update_rule(lbm_config=cfg, lbm_optimisation=opt)
    conf = ps.CreateKernelConfig(data_type=dtype, cpu_openmp=T,
                                 cpu_vectorize_info={'instruction_set': 'avx', 'assume_aligned': True,
                                                     'nontemporal': False, 'assume_inner_stride_one': True},
                                 ghost_layers=1)
    kernels.append(ps.create_kernel(rule, config=conf).compile())
dh.fill('src', 1.0 / 19)
if dst is not None:
    dh.fill('dst', 1.0 / 19)
arr = dh.cpu_arrays
sync = dh.synchronization_function(['src'])
def step(k):
    kern = kernels[k % len(kernels)]
    if pattern == 'aa':
        kern(src=arr['src'])
    else:
        kern(src=arr['src'], dst=arr['dst'])
        dh.swap('src', 'dst')
for k in range(4):
    step(k)
steps = int(sys.argv[5]) if len(sys.argv) > 5 else 20
best = 1e9
for rep in range(3):
    t = time.perf_counter()
    for k in range(steps):
        step(k)
    best = min(best, time.perf_counter() - t)
print(f"lbmpy {prec} {pattern} N={N} T={T}: {N**3 * T * steps / best / 1e6:.1f} MLUPS")
