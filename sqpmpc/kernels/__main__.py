"""``python -m sqpmpc.kernels``: compile or load every kernel and say how long it took."""

from sqpmpc.kernels.warmup import warm_up

if __name__ == "__main__":
    print(f"sqpmpc kernels ready in {warm_up():.3f} s")
