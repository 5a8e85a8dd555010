"""Opt-in: a Pinocchio model with a physics sample's masses, centres of mass and armature.

The whole-body controller keeps the *nominal* model by default (the real robot's parameters are
unknown to it too); :func:`randomized_pinocchio_model` is for studies that give the controller
the sampled dynamics (an oracle), and for checking that an engine applied a sample.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from giwbc.randomization.parameters import Nominal
from giwbc.randomization.sampling import Sample


def randomized_pinocchio_model(model: pin.Model, sample: Sample, nominal: Nominal, *, armature: bool = True) -> pin.Model:
    """A copy of ``model`` with the sample's link masses (rotational inertia scaled alike), CoMs and armature.

    ``model`` (built from the same description) is not modified. A link's inertia is added to the
    joint its body frame hangs on, so links fixed to one joint are swapped one at a time.
    """
    randomized = model.copy()
    masses, coms = sample["link_mass"], sample["link_com"]
    nominal_masses, nominal_coms = nominal.values["link_mass"], nominal.values["link_com"]
    for index, link in enumerate(nominal.links):
        mass, com, mass0, com0 = masses[index], coms[index], nominal_masses[index], nominal_coms[index]
        if mass == mass0 and np.array_equal(com, com0):
            continue
        frame = randomized.frames[randomized.getFrameId(link, pin.FrameType.BODY)]
        rotational = nominal.link_inertia[index]
        old = pin.Inertia(mass0, com0, rotational)
        new = pin.Inertia(mass, com, rotational * (mass / mass0 if mass0 > 0 else 1.0))
        joint = frame.parentJoint
        randomized.inertias[joint] = randomized.inertias[joint] - frame.placement.act(old) + frame.placement.act(new)
    if armature and "joint_armature" in sample.values:
        randomized.armature[randomized.nv - len(nominal.joints):] = sample["joint_armature"]
    return randomized
