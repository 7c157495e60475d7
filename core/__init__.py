"""Definitions shared by the compiler and the runtime, importing nothing else from rdsl."""
