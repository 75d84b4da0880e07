"""Several cameras on one body: extrinsics from shared views, fused board poses, the joint rig fit."""
