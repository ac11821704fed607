"""Learning: models of how garments deform between bodies, trained on a dataset folder. The paper's shared
deformation model (``model``, trained by ``training`` with torch), the garment fit model (``garment_model``) and
its learned placement (``placement``), trained together by ``garment_training``; ``dataset`` reads dataset
folders and builds the training fields; ``model_files`` reads every kind of model file behind one loader. Model
files are plain ``.npz`` arrays with JSON metadata, read without pickle; inference is numpy only, training needs
torch. Built on ``geometry`` only.
"""

from .dataset import Dataset, TrainingFields, build_training_fields, dataset_inputs, load_dataset
from .garment_model import GarmentFitModel, load_garment_model
from .garment_training import train_garment_fit_from_dataset, train_garment_model, train_placement_model
from .model import SharedDeformationModel, load_model
from .model_files import ModelFile, read_model_file, save_garment_fit_bundle
from .placement import MixedPlacement, NearestGarments, PlacementEnsemble, PlacementModel, load_placement_model
from .training import check_training_settings, default_threads, train_from_dataset, train_model

__all__ = ["Dataset", "load_dataset", "dataset_inputs", "build_training_fields", "TrainingFields",
           "SharedDeformationModel", "load_model", "train_model", "train_from_dataset", "check_training_settings",
           "default_threads", "GarmentFitModel",
           "load_garment_model", "PlacementModel", "PlacementEnsemble", "NearestGarments", "MixedPlacement",
           "load_placement_model", "train_garment_model", "train_placement_model", "train_garment_fit_from_dataset",
           "ModelFile", "read_model_file", "save_garment_fit_bundle"]
