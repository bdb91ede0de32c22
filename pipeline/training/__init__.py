"""Semi-supervised training of the sample CNN on labels plus must-link constraints (Mei et al.).

The loss is the paper's, Eq. (8):

    L   = L_l + L_c
    L_l = -1/M sum_i ln P_{y_i}(x_i)                        (mean cross-entropy, M labelled samples)
    L_c = gamma/N sum_n w_n (1 - sum_k P_k(x_i) P_k(x_j))   (N constraint pairs, gamma in [0, 1])

with w_n = 1 for verified pairs (the paper). Extensions (`TrainingConfig`'s defaults say which are on):
- `weighted_pairs` with pair weights < 1: automatic constraints weighted by their association score;
- `balance_weight` b > 0 adds b (ln K - H(mean_b P(x_b))) over the pair samples: maximising the
  entropy of the batch-mean prediction keeps constraints-only training from collapsing onto one
  class (the paper reports everything becoming "trunk").
- `transitive_pairs`: must-link is an equivalence, so the right side of each drawn pair is any
  other sample of the left side's track (its component in the pair graph), not only the next
  frame's: pairs then join near and far, whole and occluded views of one object;
- `closure_labels`: must-link is an equivalence, so a label holds for its whole component of
  the pair graph; every member of a component with a labelled sample is trained on that label
  (the labelled cross-entropy then draws from the closure; a component whose labelled samples
  disagree, possible only with unverified pairs, keeps just its own labels). The product's
  track review does the same: one click labels every sample of a track;
- `closure_draw="annotation"` (with closure labels): each labelled draw picks one of the given
  annotations, then a member of its component, so every annotation weighs as it does without
  constraints; "sample" draws the closure's samples alike, which weighs an annotation by the
  size of its component;
- `lr_schedule="cosine"`: the learning rate falls from lr to 0 over the run, so the last epochs,
  among which the selection rule picks, move less than a constant rate lets them.

With `balanced_labels` each batch draws its labelled samples class-uniformly (the labels of a rare
class are seen as often as those of a common one); without, uniformly, as the paper.

Each step holds m labelled samples and n = pairs_per_label * m pairs, run as one siamese forward
over [labelled; pair left sides; pair right sides]. M = 0 (constraints only) and N = 0 (labels
only) are the degenerate cases. Model selection follows the paper: the best validation F among
the epochs whose training loss is below `loss_threshold`, else the epoch of lowest loss.

Modules: `data` (samples, pool, seed), `loss`, `augment`, `split`, `sampling` (what each step draws),
`loop` (epochs, schedule, selection, checkpoints), `plots`.
"""

from __future__ import annotations

from pipeline.model import predict
from pipeline.training.augment import augment_batch, erase_rectangles, vary_intensity
from pipeline.training.data import LabelledSamples, TrainingData, seed_everything
from pipeline.training.loop import EpochRecord, TrainProgress, TrainResult, evaluate, learning_rate, train
from pipeline.training.loss import LossParts, semi_supervised_loss
from pipeline.training.plots import PLOT_FILES, write_training_plots
from pipeline.training.sampling import closure_labels, must_link_components
from pipeline.training.split import split_by_group

__all__ = [
    "LabelledSamples",
    "LossParts",
    "closure_labels",
    "erase_rectangles",
    "must_link_components",
    "TrainingData",
    "TrainProgress",
    "TrainResult",
    "evaluate",
    "predict",
    "seed_everything",
    "semi_supervised_loss",
    "split_by_group",
    "train",
    "augment_batch",
    "vary_intensity",
    "learning_rate",
    "PLOT_FILES",
    "write_training_plots",
    "EpochRecord",
]
