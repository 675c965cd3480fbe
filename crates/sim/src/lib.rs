//! MuJoCo 3.3.7 through a thin, safe wrapper, and the Meta-World v3 tasks built on it.
