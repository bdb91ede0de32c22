"""The pipeline's one typed config tree: small pydantic sections under `PipelineConfig`.

YAML files hold overrides only (`load_config`); every run writes the config it used
(`PipelineConfig.dump`). Pipeline code never reads environment variables.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from pipeline.classes import NUM_SAMPLE_CLASSES
from pipeline.errors import ConfigError
from pipeline.sensors import check_ego_box


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class SensorConfig(_Section):
    name: str = "auto"  # auto | hdl32e | hdl64e | vlp16 | path to an Ouster metadata json


class RangeImageConfig(_Section):
    width: int | None = None  # azimuth bins; None = the sensor preset's width
    min_range: float = 0.5
    max_range: float = 120.0
    # (x_min, x_max, y_min, y_max, z_min, z_max) metres in the lidar frame: the vehicle's own body,
    # whose returns are never segmented (label 0). None = the sensor's (a reader may know its
    # vehicle: nuScenes), () = none
    ego_box: tuple[float, ...] | None = None

    @field_validator("ego_box")
    @classmethod
    def _box(cls, box: tuple[float, ...] | None) -> tuple[float, ...] | None:
        if box is not None:
            check_ego_box(box, "range_image")
        return box


class GroundConfig(_Section):
    max_slope_deg: float = 10.0  # angle between consecutive beams along a column
    start_angle_deg: float = 15.0  # max slope from the sensor to the first ground point
    max_run: float = 2.0  # metres: a slope counts over at most this run between ground points
    sensor_height: float | None = None  # metres above ground; None = estimate per scan
    ground_band: float = 0.10  # points this close above the ground surface count as ground
    grid_cell: float = 2.0  # metres; cell size of the height-above-ground surface


class SegmentationConfig(_Section):
    # Range-difference thresholds |r_a - r_b| <= base + slope * min(r_a, r_b).
    vertical_base: float = 0.20
    vertical_slope: float = 0.04
    horizontal_base: float = 0.25
    horizontal_slope: float = 0.03
    # depth_clustering's beta criterion: neighbours whose connecting surface is seen at less than
    # this angle from the beam do not join (0 = off). Separates a hedge from the wall behind it
    # where only a grazing surface links them.
    angle_threshold_deg: float = Field(default=10.0, ge=0.0, lt=90.0)
    # Rough (foliage) and smooth (walls, cars) pixels do not join; a pixel is rough when most of
    # its window has a row line-fit residual above base + slope * range metres (both 0 = no
    # texture cut). A threshold growing with range, as foliage's scatter does, kept real cover
    # and raised the campus's purity and recall over a fixed 3 cm (docs/perception.md).
    texture_base: float = Field(default=0.0, ge=0.0)
    texture_slope: float = Field(default=0.0025, ge=0.0)
    # components under this many pixels join the neighbour they share the most joins with
    merge_pixels: int = Field(default=100, ge=0)
    # pixels without a return stepped over between two that may join (glass, dark paint)
    bridge_horizontal: int = Field(default=3, ge=0, le=32)
    bridge_vertical: int = Field(default=4, ge=0, le=32)
    # pixels of a nearer occluder stepped over (a pole or a person in front of a car)
    occluder_pixels: int = Field(default=10, ge=0, le=32)
    # ground points up to this many metres below a segment's lowest pixel that join it by the
    # vertical rules go back to it (wheels, the feet of walls and people; 0 = off)
    foot_height: float = Field(default=0.25, ge=0.0)
    min_points: int = 3  # segments smaller than this are dropped (label 0)


class SampleConfig(_Section):
    # valid when n > sigma and n / distance > rho. The paper's sigma=8, rho=30 (or swapped, 30/8)
    # keeps far too few segments of an HDL-32E: on 40 simulated frames association recall was
    # 0.40 with (30, 8), 0.58 with (8, 3) and 0.85 with (8, 0.5) at equal purity and precision
    # 0.99 (docs/perception.md).
    sigma: int = 8
    rho: float = 0.25
    size: int = 64  # canvas side S (paper: 256)
    cuboid_hwl: tuple[float, float, float] = (2.4, 5.0, 5.0)
    max_height: float = 6.0  # height channel 0..max_height m -> 0..255
    max_range: float = 80.0  # range channel 0..max_range m -> 0..255
    foreground_channel: bool = True  # 4th channel marks the segment's own points
    # the intensity channel: "sensor" = scaled per sensor, its 95th percentile at 0.5
    # (`pipeline.intensity`; empty when the sensor has none), "raw" = the values as read (models
    # trained before per-sensor normalisation; a checkpoint without the field reads as raw)
    intensity: str = Field(default="sensor", pattern="^(sensor|raw)$")

    @property
    def channels(self) -> int:
        return 4 if self.foreground_channel else 3


class AssociationConfig(_Section):
    min_overlap: float = 0.3  # share of a segment's points that must vote for its match
    min_score: float = 0.35
    max_centroid_distance: float = 1.5  # metres, for motion-predicted centroid matching
    # a predicted centroid's gate grows by this share of the distance its track moves in a frame
    speed_gate: float = Field(default=0.25, ge=0.0)
    # m/s: the fastest a segment that lands on nothing as a static object may have moved for a
    # first link by a motion hypothesis (highway traffic; 3 m a frame at 10 Hz)
    max_speed: float = Field(default=30.0, ge=0.0)
    use_motion_prediction: bool = True
    # reject links whose point counts differ more than this; 2.5 over 2.0 raised recall by 0.9-1.1
    # points on simulated seeds 0-3 (200 frames each) at a precision cost of <= 0.1 point
    max_point_ratio: float = 2.5
    max_height_change: float = 0.4  # metres of centroid height a predicted-centroid match may change
    ambiguity_ratio: float = 0.5  # votes split as second >= this x top between two t-1 segments = merge
    strong_share: float = 0.6  # share of votes above which the centroid jump gate is waived (>1 = never)
    # fragment links (not track links): a t and a t-1 segment that are not linked but one of which
    # has at least this share of its points on the other are pieces of one object that split,
    # merged or reshuffled; they join tracks into stitch candidates. 0 = none.
    fragment_min_share: float = Field(default=0.3, ge=0.0, le=1.0)


class ModelConfig(_Section):
    num_classes: int = NUM_SAMPLE_CLASSES  # the class table, pipeline.classes
    width: int = 32  # channels of the first conv block
    max_width: int = 128  # channel cap of later blocks (width doubles per block)
    depth: int = 4  # conv blocks
    stem_stride: int = 2  # stride of the first conv (canvas rows repeat each laser ring)
    dropout: float = 0.3


class TrainingConfig(_Section):
    """The one set of training defaults: the REST `train` job, `tracklabel experiment paper`'s
    constraint100 and the shipped model train with exactly these (`finetuning()` for fine-tuning).

    They are the paper's loss and step size (176 canvases per step) with the extensions that
    `tracklabel experiment paper` measured as better on its validation split, each against
    constraint100 by an ablation (docs/experiments/paper.md): labels spread over their must-link
    component and drawn per annotation, any two samples of a track as a pair, 58 labels + 58 pairs
    per step instead of 16 + 80, a cosine learning rate, augmentation and class-uniform label draws.
    """

    epochs: int = Field(default=8, ge=1, le=1000)  # model-selection points over the run
    steps_per_epoch: int | None = Field(default=200, ge=1, le=100_000)  # None = one pass over labels / pairs
    # m labels and n = pairs_per_label * m pairs per step: 58 + 58 runs the paper's 176 canvases
    # (16 + 80) with more labels per step, which the label closure feeds
    batch_labelled: int = Field(default=58, ge=1, le=4096)
    pairs_per_label: int = Field(default=1, ge=0, le=100)
    gamma: float = Field(default=1.0, ge=0.0, le=1.0)
    lr: float = Field(default=1e-3, gt=0.0, le=1.0)
    lr_schedule: str = Field(default="cosine", pattern="^(constant|cosine)$")  # cosine: lr -> 0 over the run
    weight_decay: float = Field(default=1e-4, ge=0.0)
    seed: int = Field(default=0, ge=0, le=2**31 - 1)
    loss_threshold: float = 0.5  # model selection: best val F among checkpoints with train loss below this
    balance_weight: float = Field(default=0.0, ge=0.0, le=10.0)  # marginal-entropy term, 0 = the paper's loss
    weighted_pairs: bool = True  # scale each pair's L_c term by its weight (association score)
    augment: bool = True  # random horizontal flip and small shifts of the canvases
    augment_shift: float = Field(default=0.0625, ge=0.0, lt=0.5)  # max shift as a fraction of the canvas side
    # with augment: the share of canvases that lose one random rectangle (a tenth to half the side
    # each way; random erasing): a view with a part missing, as occlusion and over-segmentation cut them
    augment_erase: float = Field(default=0.0, ge=0.0, le=1.0)
    # the share of canvases whose intensity channel is emptied (the geometry-only input of a
    # sensor without intensity), and the largest |log2| of a random power on the others'
    # intensity (another sensor's response): a model that reads intensity but does not need it
    intensity_drop: float = Field(default=0.0, ge=0.0, le=1.0)
    intensity_gamma: float = Field(default=0.0, ge=0.0, le=3.0)
    balanced_labels: bool = True  # draw each batch's labels class-uniformly (rare classes as often as common ones)
    transitive_pairs: bool = True  # must-link is transitive: pair a drawn sample with any sample of its track
    # must-link closure: every sample a pair chain joins to a labelled sample is trained on that
    # label too (components whose labelled members disagree keep their own labels only)
    closure_labels: bool = True
    # how the closure's labels are drawn: "annotation" (an annotation, then a member of its
    # component: each annotation weighs as without constraints) or "sample" (each labelled sample
    # alike, so an annotation weighs as much as its component is large; an ablation)
    closure_draw: str = Field(default="annotation", pattern="^(sample|annotation)$")
    # the constraint term: "paper" 1 - sum_k P_k(x_i) P_k(x_j), which is the squared difference
    # 1/2 |P_i - P_j|^2 plus the pair's mean Gini impurity (it also sharpens both sides towards
    # whatever class they lean to); "squared" the difference alone (the Pi-model's consistency)
    constraint_loss: str = Field(default="paper", pattern="^(paper|squared)$")
    # how each step's pairs are drawn: "pair" uniformly over the pairs (a component weighs as many
    # pairs as it has: long static tracks dominate), "component" a component of the must-link
    # graph uniformly, then one of its pairs
    pair_draw: str = Field(default="pair", pattern="^(pair|component)$")
    eval_batch: int = Field(default=256, ge=1)
    threads: int = Field(default=0, ge=0, le=256)  # torch CPU threads while training, 0 = torch's default
    device: str = "auto"  # auto | cpu | cuda

    def finetuning(self) -> TrainingConfig:
        """This config with fine-tuning's step budget and batch: a pretrained model trained on a
        new scene's few confirmed anchors. 800 steps of 16 anchors + 32 pairs, no label closure
        and plain label draws (the anchors are class-balanced by repetition instead,
        `pipeline.finetune.balance_classes`): chosen on a simulated development scene by
        `tracklabel experiment finetune` (docs/experiments)."""
        return self.model_copy(update=_FINETUNING)

    def for_constraints(self, kind: str) -> TrainingConfig:
        """This config for a constraint source: automatic (unverified) pairs are weighted by their
        association score and spread no labels: the closure would trust every link, and fragment
        links join other objects 9 % of the time (on the paper experiment's seed-0 route
        constraint100_auto fell to 68.3 | 66.2 train/val | D with the closure); verified pairs
        weigh 1."""
        if kind == "automatic":
            return self.model_copy(update={"weighted_pairs": True, "closure_labels": False})
        return self


_FINETUNING: dict[str, Any] = {
    "epochs": 8,
    "steps_per_epoch": 100,
    "batch_labelled": 16,
    "pairs_per_label": 2,
    "closure_labels": False,
    "balanced_labels": False,
}


class PipelineConfig(_Section):
    sensor: SensorConfig = SensorConfig()
    range_image: RangeImageConfig = RangeImageConfig()
    ground: GroundConfig = GroundConfig()
    segmentation: SegmentationConfig = SegmentationConfig()
    samples: SampleConfig = SampleConfig()
    association: AssociationConfig = AssociationConfig()
    model: ModelConfig = ModelConfig()
    training: TrainingConfig = TrainingConfig()

    def dump(self, path: str | Path) -> None:
        """Write the full config actually used, as YAML."""
        Path(path).write_text(yaml.safe_dump(self.model_dump(mode="json"), sort_keys=False))

    def override(self, updates: dict) -> PipelineConfig:
        """A copy with nested `updates` applied ({"samples": {"size": 256}})."""
        return _validate(merge_nested(self.model_dump(), updates), "overrides")


def merge_nested(base: dict, updates: dict) -> dict:
    """`base` with nested `updates` applied (dicts merged key by key, anything else replaced)."""
    out = dict(base)
    for key, value in updates.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge_nested(out[key], value)
        else:
            out[key] = value
    return out


def _validate(data: dict, where: str) -> PipelineConfig:
    try:
        return PipelineConfig.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        field = ".".join(str(p) for p in first["loc"])
        raise ConfigError(f"{where}: field {field}: {first['msg']}") from exc


def load_config(path: str | Path | None = None) -> PipelineConfig:
    """Defaults, with the overrides of a YAML file applied when `path` is given."""
    if path is None:
        return PipelineConfig()
    p = Path(path)
    data = read_yaml_mapping(p, "config must be a mapping of sections")
    return _validate(merge_nested(PipelineConfig().model_dump(), data), str(p))


def read_yaml_mapping(path: Path, not_a_mapping: str) -> dict:
    """A YAML file's top-level mapping (empty file: {}); ConfigError naming the file when it
    cannot be read or parsed, or with `not_a_mapping` when it holds something else."""
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: cannot read config: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: {not_a_mapping}")
    return data
