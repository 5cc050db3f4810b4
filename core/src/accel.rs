//! The BVH (the only module that talks to obvhs).
