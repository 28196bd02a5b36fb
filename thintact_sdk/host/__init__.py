"""The host the SDK runs on: CPU capabilities, BLAS and kernel threads, the measured GEMM roofline, progress output."""
