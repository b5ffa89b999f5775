// crate::p::Q in a comment; /* crate::p::helper */ too
/// A doc link to [`crate::p::Q`] and [`super::p`].
pub struct Ay;
pub fn name() -> &'static str {
    let _raw = r#"crate::p::Q"#;
    let _c = '"';
    "crate::p::Q"
}
#[cfg(test)]
mod tests {
    use super::*;
    use crate::p::Q;
    #[test]
    fn uses_everything() {
        let _ = (Q, Ay, name());
        crate::p::helper();
    }
}
