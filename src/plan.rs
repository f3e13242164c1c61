//! View generation: joint configurations from which the camera sees the robot base.
