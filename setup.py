"""Build the optional native kernels of the static update (kms2pin/_kernels.c).

Everything else is configured in pyproject.toml.  The extension is optional: without a
C compiler the install still succeeds and kms2pin uses the kernels' NumPy twins instead
(kms2pin/_numpy_kernels.py; ``kms2pin.native.ENABLED`` says which is in use).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "kms2pin._kernels",
            sources=["kms2pin/_kernels.c"],
            # -fopenmp-simd: the kernels' `omp simd` loops vectorize (no OpenMP runtime);
            # no -ffast-math: exp_nonpositive needs IEEE rounding
            extra_compile_args=["-O3", "-fopenmp-simd", "-fno-math-errno", "-fno-trapping-math"],
            optional=True,
        )
    ]
)
