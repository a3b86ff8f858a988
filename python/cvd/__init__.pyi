from os import PathLike
from typing import Any, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

_Path = Union[str, "PathLike[str]"]

class Mesh:
    def __new__(cls, vertices: npt.ArrayLike, tets: npt.ArrayLike) -> "Mesh": ...
    @property
    def vertices(self) -> npt.NDArray[np.float64]: ...
    @property
    def tets(self) -> npt.NDArray[np.int64]: ...
    @property
    def volume(self) -> float: ...
    def quality(self) -> dict[str, float]: ...

class Cells:
    volume: npt.NDArray[np.float64]
    centroid: npt.NDArray[np.float64]
    energy: npt.NDArray[np.float64]
    e_vol: float
    mesh_volume: float
    counters: dict[str, int]
    timings: dict[str, float]
    adjacency: Optional[dict[str, npt.NDArray[Any]]]
    polyhedra: Optional[list[dict[str, Any]]]
    def to_pyvista(self) -> Any: ...
    def adjacency_matrix(self) -> Any: ...

KERNELS: bool

def builtin(name: str, resolution: Optional[int] = None) -> Mesh: ...
def read_mesh(path: _Path) -> Mesh: ...
def mesh_surface(path: _Path, resolution: Optional[int] = None) -> Mesh: ...
def sample(mesh: Mesh, n: int, seed: int = 1) -> npt.NDArray[np.float64]: ...
def clipped_voronoi(
    mesh: Mesh,
    sites: npt.ArrayLike,
    *,
    backend: str = "auto",
    strategy: str = "tet-cell",
    pairing: str = "flood",
    density: Optional[npt.ArrayLike] = None,
    faces: bool = False,
    polyhedra: bool = False,
    weights: Optional[npt.ArrayLike] = None,
    memory_budget: Optional[int] = None,
) -> Cells: ...
class ParticleCells:
    cells: Cells
    points: npt.NDArray[np.float64]
    volumes: npt.NDArray[np.float64]
    centroids: npt.NDArray[np.float64]
    areas: Optional[npt.NDArray[np.float64]]
    neighbor_counts: Optional[npt.NDArray[np.int64]]
    coordination: Optional[npt.NDArray[np.int64]]
    voronoi_index: Optional[npt.NDArray[np.int64]]
    max_face_order: Optional[npt.NDArray[np.int64]]
    adjacency: Optional[dict[str, npt.NDArray[Any]]]
    origin: npt.NDArray[np.float64]
    vectors: npt.NDArray[np.float64]
    periodic: tuple[bool, bool, bool]
    reused: int
    def neighbor_pairs(
        self,
    ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.int64]]: ...

def particle_voronoi(
    points: npt.ArrayLike,
    box: Any,
    *,
    origin: Optional[Sequence[float]] = None,
    periodic: Union[bool, Sequence[bool]] = True,
    radii: Optional[npt.ArrayLike] = None,
    voronoi_index: bool = True,
    edge_threshold: float = 0.0,
    relative_edge_threshold: float = 0.0,
    face_threshold: float = 0.0,
    relative_face_threshold: float = 0.0,
    polyhedra: bool = False,
    faces: bool = True,
    backend: str = "auto",
    memory_budget: Optional[int] = None,
) -> ParticleCells: ...

class ParticleVoronoi:
    voronoi_index: bool
    thresholds: tuple[float, float, float, float]
    polyhedra: bool
    faces: bool
    backend: str
    reuse: bool
    reused: int
    def __init__(
        self,
        *,
        voronoi_index: bool = True,
        edge_threshold: float = 0.0,
        relative_edge_threshold: float = 0.0,
        face_threshold: float = 0.0,
        relative_face_threshold: float = 0.0,
        polyhedra: bool = False,
        faces: bool = True,
        backend: str = "auto",
        reuse: bool = True,
        memory_budget: Optional[int] = None,
    ) -> None: ...
    def compute(
        self,
        points: npt.ArrayLike,
        box: Any,
        *,
        origin: Optional[Sequence[float]] = None,
        periodic: Union[bool, Sequence[bool]] = True,
        radii: Optional[npt.ArrayLike] = None,
    ) -> ParticleCells: ...
def periodic_voronoi(
    sites: npt.ArrayLike,
    lo: Sequence[float],
    hi: Sequence[float],
    *,
    backend: str = "auto",
    faces: bool = False,
    weights: Optional[npt.ArrayLike] = None,
    memory_budget: Optional[int] = None,
) -> tuple[Cells, npt.NDArray[np.float64]]: ...
def lloyd(
    mesh: Mesh,
    sites: npt.ArrayLike,
    iterations: int,
    *,
    optimizer: str = "lloyd",
    backend: str = "auto",
    density: Optional[npt.ArrayLike] = None,
    progress: bool = False,
) -> tuple[npt.NDArray[np.float64], dict[str, npt.NDArray[Any]]]: ...
def transport(
    mesh: Mesh,
    sites: npt.ArrayLike,
    capacities: Optional[npt.ArrayLike] = None,
    *,
    backend: str = "auto",
    density: Optional[npt.ArrayLike] = None,
    weights: Optional[npt.ArrayLike] = None,
    tolerance: float = 1e-6,
    max_steps: int = 50,
    return_record: bool = False,
) -> Union[npt.NDArray[np.float64], tuple[npt.NDArray[np.float64], dict[str, Any]]]: ...
def devices() -> list[dict[str, Any]]: ...
