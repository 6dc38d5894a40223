"""``python -m jaxlc``: versions, JAX backend and devices, precision, optional parts."""

from jaxlc.info import print_info

if __name__ == "__main__":
    print_info()
