"""Generators: the registry and one module per generator family."""

from ipm.generators.base import GENERATORS, Generator, all_generators, get_generator, register_generator

__all__ = ["GENERATORS", "Generator", "all_generators", "get_generator", "register_generator"]
