//! OBJ, MTL and manifest text. Cases are added with the fixes (issue 18).
