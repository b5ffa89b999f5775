pub fn inner() {
    crate::shout!();
}
