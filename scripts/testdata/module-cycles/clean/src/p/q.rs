use super::helper;
pub struct Q;
pub fn go() {
    helper();
    let _ = crate::Ay;
}
