"""Pure numerical functions: arrays in, arrays or small dataclasses out; no I/O, no drivers."""
