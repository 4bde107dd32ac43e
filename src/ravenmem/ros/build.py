"""`ravenmem ros setup`: build the ROS 2 interface packages the node needs into the active Python
environment, with plain cmake, so that `from ravenmem_msgs.srv import Ask` works with nothing
sourced or exported.

Three packages: `ravenmem_msgs` (ours, next to this module), and, only when they are not
importable already (a ROS 2 distribution has them), `tf2_msgs` (its `TFMessage`, which /tf and
/tf_static carry) and `nav2_msgs` (its `NavigateToPose` action). The last two are written here
from their documented interfaces; only the parts the node uses are built.

Facts about ROS 2 from PyPI (the `ros` extra, the ros-python-wheels build of Kilted) that this
handles, found by building here:
- the wheels' dependency lists miss ament_cmake / rosidl typesupport packages an interface build
  needs: the `ros` extra lists them (`missing()` names any that are absent);
- their exported cmake targets carry the include folders of the machine that built them
  (`/opt/python/cp311-cp311/include/python3.11`, `.../numpy/_core/include`): a cmake hook
  (`FIXUP`, run at the end of the project's configuration) points them at this Python's;
- the build needs `AMENT_PREFIX_PATH` / `CMAKE_PREFIX_PATH` at the environment's prefix, and
  `catkin_pkg`, `em` (empy) and `lark` in the Python that cmake runs;
- the wheels' `ros_wheels_bootstrapper` re-executes every Python of the environment with
  `<prefix>/lib` on `LD_LIBRARY_PATH`: installed there, the built libraries are found, and the
  RPATH set here finds them without it.

Idempotent: a package is rebuilt only when its interface files changed since it was built
(a hash kept in `<prefix>/share/<package>/ravenmem-interface.sha256`) or it does not import.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from ..errors import InputError, MissingDependencyError

STAMP = "ravenmem-interface.sha256"
PYTHON_NEEDS = {
    "catkin_pkg": "catkin-pkg",
    "em": "empy",
    "lark": "lark",
    "ament_package": "ros-ament-package",
}
CMAKE_NEEDS = (
    "ament_cmake",
    "rosidl_default_generators",
    "rosidl_typesupport_fastrtps_c",
    "rosidl_typesupport_introspection_c",
    "rosidl_generator_py",
    "ament_cmake_ros_core",
    "geometry_msgs",
    "sensor_msgs",
)

FIXUP = """\
# ravenmem ros setup: the ROS 2 wheels' exported targets name the include folders of the machine
# that built them; at the end of the configuration, point them at this Python's and numpy's
function(_ravenmem_fix_imported)
  get_directory_property(_targets DIRECTORY "${CMAKE_SOURCE_DIR}" IMPORTED_TARGETS)
  foreach(_t IN LISTS _targets)
    get_target_property(_dirs ${_t} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT _dirs)
      continue()
    endif()
    set(_new "")
    foreach(_d IN LISTS _dirs)
      if(_d MATCHES "/include/python3\\\\.[0-9]+$" AND NOT EXISTS "${_d}")
        set(_d "${RAVENMEM_PYTHON_INCLUDE}")
      elseif(_d MATCHES "numpy/(_core|core)/include$" AND NOT EXISTS "${_d}")
        set(_d "${RAVENMEM_NUMPY_INCLUDE}")
      endif()
      list(APPEND _new "${_d}")
    endforeach()
    set_target_properties(${_t} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_new}")
  endforeach()
endfunction()
cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _ravenmem_fix_imported)
"""

# tf2_msgs/msg/TFMessage and nav2_msgs/action/NavigateToPose, from their documented interfaces
TF2_MSGS = {"msg/TFMessage.msg": "geometry_msgs/TransformStamped[] transforms\n"}
NAV2_MSGS = {
    "action/NavigateToPose.action": (
        "# goal\ngeometry_msgs/PoseStamped pose\nstring behavior_tree\n---\n"
        "# result\nuint16 error_code\nstring error_msg\n---\n"
        "# feedback\ngeometry_msgs/PoseStamped current_pose\n"
        "builtin_interfaces/Duration navigation_time\n"
        "builtin_interfaces/Duration estimated_time_remaining\n"
        "int16 number_of_recoveries\nfloat32 distance_remaining\n"
    )
}


@dataclass(frozen=True)
class Package:
    """An interface package: its name, its files ({relative path: text}), its dependencies,
    and whether it is built only when missing (someone else's package)."""

    name: str
    files: dict[str, str]
    depends: tuple[str, ...]
    only_if_missing: bool = False

    @property
    def digest(self) -> str:
        h = hashlib.sha256()
        for path in sorted(self.files):
            h.update(path.encode() + b"\0" + self.files[path].encode() + b"\0")
        return h.hexdigest()


def ravenmem_msgs() -> Package:
    """Our package, read from the folder next to this module (also `colcon build`-able)."""
    root = resources.files("ravenmem.ros") / "ravenmem_msgs"
    files: dict[str, str] = {}
    for name in ("package.xml", "CMakeLists.txt"):
        files[name] = (root / name).read_text(encoding="utf-8")
    for sub in ("msg", "srv", "action"):
        folder = root / sub
        if folder.is_dir():
            for f in folder.iterdir():
                files[f"{sub}/{f.name}"] = f.read_text(encoding="utf-8")
    return Package("ravenmem_msgs", files, ())


def generated(name: str, interfaces: dict[str, str], depends: tuple[str, ...]) -> Package:
    """A package.xml and CMakeLists.txt around interface files (tf2_msgs, nav2_msgs)."""
    deps = "".join(f"  <depend>{d}</depend>\n" for d in depends)
    xml = (
        '<?xml version="1.0"?>\n<package format="3">\n'
        f"  <name>{name}</name>\n  <version>0.0.0</version>\n"
        f"  <description>{name} interfaces, built by ravenmem ros setup</description>\n"
        '  <maintainer email="ravenmem@example.org">ravenmem</maintainer>\n'
        "  <license>Apache-2.0</license>\n"
        "  <buildtool_depend>ament_cmake</buildtool_depend>\n"
        "  <buildtool_depend>rosidl_default_generators</buildtool_depend>\n"
        f"{deps}  <exec_depend>rosidl_default_runtime</exec_depend>\n"
        "  <member_of_group>rosidl_interface_packages</member_of_group>\n"
        "  <export><build_type>ament_cmake</build_type></export>\n</package>\n"
    )
    finds = "".join(f"find_package({d} REQUIRED)\n" for d in depends)
    files = " ".join(f'"{p}"' for p in sorted(interfaces))
    cmake = (
        f"cmake_minimum_required(VERSION 3.8)\nproject({name})\n"
        "find_package(ament_cmake REQUIRED)\nfind_package(rosidl_default_generators REQUIRED)\n"
        f"{finds}rosidl_generate_interfaces(${{PROJECT_NAME}} {files} DEPENDENCIES {' '.join(depends)})\n"
        "ament_export_dependencies(rosidl_default_runtime)\nament_package()\n"
    )
    return Package(name, {"package.xml": xml, "CMakeLists.txt": cmake, **interfaces}, depends, True)


def packages() -> list[Package]:
    return [
        ravenmem_msgs(),
        generated("tf2_msgs", TF2_MSGS, ("geometry_msgs",)),
        generated("nav2_msgs", NAV2_MSGS, ("builtin_interfaces", "geometry_msgs")),
    ]


def missing(prefix: Path) -> list[str]:
    """What an interface build lacks here, as one list of names (empty: nothing)."""
    out = []
    if shutil.which("cmake") is None:
        out.append("cmake (apt-get install cmake, or pip install cmake)")
    if not any(shutil.which(c) for c in (os.environ.get("CXX", ""), "c++", "g++", "clang++") if c):
        out.append("a C++ compiler (apt-get install g++)")
    if importlib.util.find_spec("rclpy") is None:
        out.append("rclpy (pip install 'ravenmem[ros]')")
    out += [f"{pip} (pip install 'ravenmem[ros]')" for mod, pip in PYTHON_NEEDS.items() if not _has(mod)]
    # the environment's own prefix, and a sourced ROS 2 distribution's (/opt/ros/<distro>)
    prefixes = [prefix, *(Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p)]
    out += [
        f"{pkg} (pip install 'ravenmem[ros]')"
        for pkg in CMAKE_NEEDS
        if not any((p / "share" / pkg / "cmake").is_dir() for p in prefixes)
    ]
    return out


def _has(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def state(pkg: Package, prefix: Path) -> str:
    """`current` (built by us from these files), `present` (someone else's, importable),
    `stale` (ours, from other files) or `missing`."""
    stamp = prefix / "share" / pkg.name / STAMP
    ours = stamp.is_file()
    if ours and stamp.read_text().strip() == pkg.digest and _has(pkg.name):
        return "current"
    if not ours and _has(pkg.name):
        return "present" if pkg.only_if_missing else "stale"
    return "stale" if ours else "missing"


def setup(
    prefix: Path | None = None,
    force: bool = False,
    jobs: int = 2,
    log: Callable[[str], None] = lambda s: None,
) -> dict[str, str]:
    """Build what is missing or stale; {package: what was done}. A one-line
    `MissingDependencyError` names what the build lacks."""
    prefix = Path(prefix or sys.prefix)
    done: dict[str, str] = {}
    todo = []
    for pkg in packages():
        st = state(pkg, prefix)
        if st == "present" or (st == "current" and not force):
            done[pkg.name] = "up to date" if st == "current" else "installed already"
        else:
            todo.append(pkg)
    lacking = missing(prefix) if todo else []
    if lacking:
        raise MissingDependencyError("ros setup needs " + "; ".join(lacking))
    for pkg in todo:
        log(f"building {pkg.name} into {prefix} (about a minute)")
        build(pkg, prefix, jobs)
        importlib.invalidate_caches()
        done[pkg.name] = "built"
    return done


def build(pkg: Package, prefix: Path, jobs: int = 2) -> None:
    """cmake configure, build and install of one package into `prefix`."""
    import numpy

    with tempfile.TemporaryDirectory(prefix=f"ravenmem-{pkg.name}-") as tmp:
        src, out = Path(tmp) / "src", Path(tmp) / "build"
        for rel, text in pkg.files.items():
            (src / rel).parent.mkdir(parents=True, exist_ok=True)
            (src / rel).write_text(text, encoding="utf-8")
        (Path(tmp) / "fixup.cmake").write_text(FIXUP, encoding="utf-8")
        env = dict(os.environ)
        for var in ("AMENT_PREFIX_PATH", "CMAKE_PREFIX_PATH"):
            env[var] = os.pathsep.join(p for p in (str(prefix), env.get(var, "")) if p)
        env["PATH"] = os.pathsep.join((str(Path(sys.executable).parent), env.get("PATH", "")))
        configure = [
            "cmake",
            "-S",
            str(src),
            "-B",
            str(out),
            f"-DCMAKE_INSTALL_PREFIX={prefix}",
            f"-DPython3_EXECUTABLE={sys.executable}",
            "-DBUILD_TESTING=OFF",
            "-DCMAKE_BUILD_TYPE=Release",
            f"-DCMAKE_INSTALL_RPATH={prefix / 'lib'}",
            f"-DCMAKE_PROJECT_INCLUDE={Path(tmp) / 'fixup.cmake'}",
            f"-DRAVENMEM_PYTHON_INCLUDE={sysconfig.get_paths()['include']}",
            f"-DRAVENMEM_NUMPY_INCLUDE={numpy.get_include()}",
        ]
        for step, cmd in (
            ("configure", configure),
            ("build", ["cmake", "--build", str(out), "-j", str(max(1, jobs))]),
            ("install", ["cmake", "--install", str(out)]),
        ):
            run = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
            if run.returncode != 0:
                raise InputError(f"ros setup: {pkg.name}: cmake {step} failed: {_first_error(run)}")
        stamp = prefix / "share" / pkg.name / STAMP
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.write_text(pkg.digest + "\n")


def _first_error(run: subprocess.CompletedProcess[str]) -> str:
    """The first line that says what went wrong (cmake prints pages)."""
    lines = [ln.strip() for ln in (run.stderr + "\n" + run.stdout).splitlines() if ln.strip()]
    for ln in lines:
        if "error" in ln.lower() or "not found" in ln.lower() or "could not" in ln.lower():
            return ln[:300]
    return (lines[-1] if lines else f"exit {run.returncode}")[:300]
