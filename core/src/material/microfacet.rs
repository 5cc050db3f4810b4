//! GGX (Trowbridge–Reitz) microfacet distribution with visible-normal sampling.
