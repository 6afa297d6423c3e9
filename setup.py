"""Builds the compiled core (the models' rollouts and linearizations, the MPC's control step), the extension
module stdm_drake._core (its C++ sources in stdm_drake/core/), at install: nanobind binds it, Eigen's and
Pinocchio's headers come from the build requirements in pyproject.toml (cmeel-eigen, libpinocchio; Pinocchio
used header-only, so the extension needs no library at run time). It is compiled for the installing machine's CPU (-march=native: the float32 networks' matrix
products in its widest vector instructions); a copy moved to an older CPU stops with an illegal instruction:
install it there. Its two translation units compile in parallel. Everything else about the package is in
pyproject.toml.

A machine without a C++17 compiler, or a build that fails, stops the install with one line saying so
(docs/guides/install.md); there is no silent fall-back to the numpy code."""
import pathlib
import sys
import sysconfig

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

CORE = "stdm_drake/core"


class BuildCore(build_ext):
    """build_ext with the include paths found in the build environment and a one-line failure."""

    def build_extensions(self):
        import shutil
        compiler = self.compiler.compiler_cxx[0] if getattr(self.compiler, "compiler_cxx", None) else "c++"
        if shutil.which(compiler) is None:
            sys.exit(f"stdm-drake: no C++ compiler ({compiler!r} not found): the compiled MPC control step needs one "
                     "(Debian/Ubuntu: apt-get install g++); see docs/guides/install.md")
        import nanobind
        import cmeel
        prefix = pathlib.Path(cmeel.__file__).resolve().parent.parent / "cmeel.prefix"
        if not (prefix / "include" / "pinocchio").is_dir() or not (prefix / "include" / "eigen3").is_dir():
            sys.exit(f"stdm-drake: Pinocchio's or Eigen's headers are missing under {prefix} (build requirements "
                     "libpinocchio and cmeel-eigen of pyproject.toml)")
        nanobind_root = pathlib.Path(nanobind.__file__).resolve().parent
        if self._reuse_inplace_build():
            return
        for extension in self.extensions:
            extension.sources.append(str(nanobind_root / "src" / "nb_combined.cpp"))
            extension.include_dirs += [nanobind.include_dir(), str(nanobind_root / "ext" / "robin_map" / "include"),
                                       str(prefix / "include"), str(prefix / "include" / "eigen3"),
                                       sysconfig.get_paths()["include"]]
        self._compile_in_parallel()
        try:
            super().build_extensions()
        except Exception as error:   # (the compiler's own output is above this line)
            sys.exit(f"stdm-drake: the compiled MPC control step did not build ({type(error).__name__}: "
                     f"{str(error).splitlines()[0] if str(error) else ''}); see docs/guides/install.md")


    def _compile_in_parallel(self) -> None:
        """The compiler's `compile` with one process per source (the extension's sources take minutes each)."""
        import concurrent.futures
        import os
        compile_one = self.compiler.compile

        def compile_all(sources, *arguments, **options):
            workers = max(1, min(len(sources), os.cpu_count() or 1))
            with concurrent.futures.ThreadPoolExecutor(workers) as pool:
                parts = list(pool.map(lambda source: compile_one([source], *arguments, **options), sources))
            return [path for part in parts for path in part]

        self.compiler.compile = compile_all

    def _reuse_inplace_build(self) -> bool:
        """Copy the extension built in place in this source tree (by `pip install -e .`) where it is newer than all
        its sources, instead of compiling it again (a wheel built from the checkout, as the tests build one)."""
        import shutil
        if self.inplace:
            return False
        for extension in self.extensions:
            built = pathlib.Path(*extension.name.split(".")).with_name(
                extension.name.rsplit(".", 1)[-1] + sysconfig.get_config_var("EXT_SUFFIX"))
            sources = [pathlib.Path(name) for name in (*extension.sources, *extension.depends) if "nanobind" not in name]
            if not built.is_file() or any(source.stat().st_mtime >= built.stat().st_mtime for source in sources):
                return False
        for extension in self.extensions:
            built = pathlib.Path(*extension.name.split(".")).with_name(
                extension.name.rsplit(".", 1)[-1] + sysconfig.get_config_var("EXT_SUFFIX"))
            target = pathlib.Path(self.get_ext_fullpath(extension.name))
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(built, target)
        return True


core = Extension(
    "stdm_drake._core",
    sources=[f"{CORE}/bindings.cpp", f"{CORE}/rigid_body.cpp"],
    depends=[f"{CORE}/control_step.hpp", f"{CORE}/rigid_body.hpp", f"{CORE}/small_gemm.hpp"],
    language="c++",
    define_macros=[("BOOST_MPL_LIMIT_LIST_SIZE", "30"),
                   ("BOOST_MPL_LIMIT_VECTOR_SIZE", "30"), ("BOOST_MPL_CFG_NO_PREPROCESSED_HEADERS", None),
                   ("BOOST_FUSION_INVOKE_MAX_ARITY", "12"), ("NDEBUG", None)],
    # Pinocchio header-only and every unit for the same instruction set: Eigen's types change layout with it, so
    # code built for another (libpinocchio_default's precompiled algorithms are generic x86-64) must not share them
    # -g0: no debug information (Python's own CFLAGS carry -g): 235 MB of it made a 49 MB wheel that every install
    # and the tests' wheel build zipped and unzipped; the code is the same with or without it
    extra_compile_args=["-std=c++17", "-O3", "-march=native", "-fvisibility=hidden", "-w", "-g0"],
)

setup(ext_modules=[core], cmdclass={"build_ext": BuildCore})
