"""Losses: MK-MMD (with Gretton et al.'s optimal kernel weights), Deep CORAL, VTLoss (thesis ch.7); beyond it
DDC's linear-kernel MMD, DANN gradient reversal, CDAN+E's conditioning, information maximisation, minimum
class confusion, maximum classifier discrepancy, PointDAN's node alignment, the stepwise adaptive feature
norm, DSAN's class-conditional LMMD and SimCLR's NT-Xent."""

from vtlearn.losses.afn import adaptive_feature_norm
from vtlearn.losses.cdan import entropy_weights, multilinear_map
from vtlearn.losses.contrastive import nt_xent
from vtlearn.losses.coral import coral, covariance
from vtlearn.losses.dann import GradientReversal, dann_lambda, domain_adversarial_loss, grad_reverse
from vtlearn.losses.info_max import information_maximization
from vtlearn.losses.kernel_choice import linear_time_statistics, optimal_kernel_weights
from vtlearn.losses.lmmd import local_mmd
from vtlearn.losses.mcc import minimum_class_confusion
from vtlearn.losses.mcd import classifier_discrepancy, mcd_adversarial_loss
from vtlearn.losses.mmd import gaussian_bandwidths, linear_kernel_mmd, mk_mmd, multi_kernel_matrix
from vtlearn.losses.pointdan import node_alignment_loss
from vtlearn.losses.vtloss import VTLoss

__all__ = [
    "coral",
    "covariance",
    "mk_mmd",
    "linear_kernel_mmd",
    "local_mmd",
    "gaussian_bandwidths",
    "multi_kernel_matrix",
    "linear_time_statistics",
    "optimal_kernel_weights",
    "VTLoss",
    "GradientReversal",
    "grad_reverse",
    "dann_lambda",
    "domain_adversarial_loss",
    "multilinear_map",
    "entropy_weights",
    "information_maximization",
    "minimum_class_confusion",
    "classifier_discrepancy",
    "mcd_adversarial_loss",
    "node_alignment_loss",
    "adaptive_feature_norm",
    "nt_xent",
]
